"""Colour accents: a share of a species' trees turned toward another leaf colour (``[[species]] accents``).

The truths are the closed forms of :mod:`forest.tint` (the share drawn per tree, w = 1 giving the
accent's albedo exactly, Oklab's mix measured by colour-science), the trees without an accent keeping
their tints to the bit, and forest_path's first-hit albedo of each tree, which must be the accent's
colour where the draw says so.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import run_forest
from test_bark import SCENE, tree_albedo
from test_render import trees

from forest.config import parse_config
from forest.render import render_scene
from forest.scatter.models import model_settings
from forest.scene import load_scene
from forest.tint import Accents, accent_table, leaf_colour, mix_oklab, tint_params, tree_tints

from render_fixtures import BoxLibrary

BROADLEAF = np.array([[0.097, 0.178, 0.027]])  # a broadleaf's leaf albedo
FLUSH, FLOWER = (0.25, 0.06, 0.03), (0.5, 0.4, 0.05)


def _accents(shares=(0.05, 0.03), amounts=((1.0, 1.0), (0.7, 1.0))) -> Accents:
    return Accents(
        share=np.array([shares], np.float64),
        colour=np.array([[FLUSH, FLOWER][: len(shares)]], np.float64),
        amount=np.array([amounts[: len(shares)]], np.float64),
    )


def test_each_accent_takes_its_share_and_the_others_keep_their_tints_to_the_bit():
    n = 40_000
    ids, species = np.arange(n) * 3 + 1, np.zeros(n, np.int64)
    ones = np.ones((n, 3), np.float32)
    acc = _accents()
    k, w = acc.draw(species, ids, 7)
    for j, share in enumerate((0.05, 0.03)):
        got = (k == j).mean()
        assert abs(got - share) < 4.0 * np.sqrt(share * (1 - share) / n), (j, got)  # 4 σ of the binomial
    assert ((w[k == 1] >= 0.7) & (w[k == 1] < 1.0)).all() and (w[k == 0] == 1.0).all()
    assert np.ptp(w[k == 1]) > 0.25  # spread over the range
    plain = tree_tints(ones, species, ids, 7, BROADLEAF, [12.0], [0.2])
    accented = tree_tints(ones, species, ids, 7, BROADLEAF, [12.0], [0.2], acc)
    assert accented[k < 0].tobytes() == plain[k < 0].tobytes()
    # Keyed by tree id and seed: a subset in another order draws the same, another seed not.
    order = np.random.default_rng(2).permutation(n)[:900]
    again = tree_tints(ones[order], species[order], ids[order], 7, BROADLEAF, [12.0], [0.2], acc)
    np.testing.assert_array_equal(again, accented[order])
    assert not np.array_equal(acc.draw(species, ids, 8)[0], k)


def test_a_full_accent_is_its_colour_and_a_partial_one_is_oklabs_mix():
    """w = 1 without jitter: the leaf albedo c ⊙ t is the accent's; w < 1: Oklab's mix, measured by colour-science."""
    import colour

    n = 4000
    ids, species = np.arange(n), np.zeros(n, np.int64)
    m = (0.8 + 0.4 * np.random.default_rng(1).random((n, 3))).astype(np.float32)  # a colour map's tint
    acc = _accents()
    k, w = acc.draw(species, ids, 3)
    t = tree_tints(m, species, ids, 3, BROADLEAF, [0.0], [0.0], acc)
    leaf = BROADLEAF * t.astype(np.float64)
    np.testing.assert_allclose(leaf[k == 0], np.broadcast_to(FLUSH, leaf[k == 0].shape), rtol=1e-5)
    np.testing.assert_array_equal(t[k < 0], m[k < 0])  # the map's tint alone

    def lab(rgb):
        return colour.XYZ_to_Oklab(colour.sRGB_to_XYZ(rgb, apply_cctf_decoding=False))

    rows = np.flatnonzero(k == 1)
    start = BROADLEAF * m[rows].astype(np.float64)
    expect = (1.0 - w[rows, None]) * lab(start) + w[rows, None] * lab(np.array(FLOWER))
    np.testing.assert_allclose(lab(leaf[rows]), expect, atol=2e-5)
    np.testing.assert_allclose(mix_oklab(start, np.broadcast_to(FLOWER, start.shape), w[rows]), leaf[rows], rtol=1e-5)


def test_jittered_accents_vary_around_the_accent():
    """The tree's own hue/value jitter applies after the accent: accented crowns are not one flat colour."""
    n = 20_000
    ids, species = np.arange(n), np.zeros(n, np.int64)
    acc = _accents(shares=(0.2,), amounts=((1.0, 1.0),))
    k, _ = acc.draw(species, ids, 5)
    leaf = BROADLEAF * tree_tints(np.ones((n, 3), np.float32), species, ids, 5, BROADLEAF, [10.0], [0.2], acc)
    red = leaf[k == 0]
    assert np.ptp(red[:, 0]) > 0.1 * FLUSH[0]
    assert (red[:, 0] > 2.0 * red[:, 1]).all()  # still red, every one


def test_a_scene_retints_with_the_configs_accents(tmp_path):
    """A set scattered without accents, loaded with a config that has them, shows them (the Scene recomputes
    the tints, as for the jitter); the exporters' column, ``tree_tints()``, carries them."""
    from test_scene import four_trees, make_config

    library = BoxLibrary(tmp_path / "lib")
    inst = four_trees()
    inst.meta["inputs"] = {}  # a scatter's set (not one made elsewhere): the Scene redoes its tints
    cfg = make_config(tmp_path)
    over = {"species[0].colour_jitter": {"hue": 0.0, "value": 0.0}}
    plain = load_scene(cfg.with_overrides(over), inst, library=library)
    over["species[0].accents"] = [{"share": 1.0, "colour": list(FLUSH), "amount": [1.0, 1.0]}]
    red = load_scene(cfg.with_overrides(over), inst, library=library)
    c = np.array(leaf_colour(library.resolve("box")))
    np.testing.assert_allclose(c * red.tree_tints(), np.broadcast_to(FLUSH, (len(inst), 3)), rtol=1e-5)
    assert not np.allclose(plain.tree_tints(), red.tree_tints())


#: Six boxes of the ``box`` species with two accents: the shares put, with the scene's seed (5), two boxes in
#: each accent and two in none.
BOXES = """[[species]]
model = "box"
percent = 100
colour_jitter = {{ hue = 0.0, value = 0.0 }}
accents = [{{ share = 0.72, colour = {flush}, amount = [1.0, 1.0] }},
           {{ share = 0.04, colour = {flower}, amount = [1.0, 1.0] }}]
"""
POSITIONS = [[x, 0.0, z] for x in (-12.0, 0.0, 12.0) for z in (-6.0, 6.0)]


def test_forest_path_renders_each_accented_tree_in_its_accent(tmp_path):
    """Six boxes from above: each box's first-hit albedo is its accent's colour where the draw gave it one and
    the species' own colour elsewhere."""
    library = BoxLibrary(tmp_path / "lib")
    species = BOXES.format(flush=list(FLUSH), flower=list(FLOWER))
    text = SCENE.format(head="", render='aovs = ["albedo"]', species=species)
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    base = dataclasses.replace(trees(POSITIONS, scale=2.0), extent=(-30.0, -30.0, 30.0, 30.0))
    params = tint_params(model_settings(cfg), (library.resolve("box"),), cfg.seed)
    k, _ = accent_table(model_settings(cfg)).draw(base.species, base.id, cfg.seed)
    assert set(k.tolist()) == {-1, 0, 1}, k  # the seed gives all three kinds among the six
    inst = dataclasses.replace(base, tint=params.tints(np.ones((len(base), 3), np.float32), base.species, base.id))
    scene = load_scene(cfg, inst, library=library)
    render_scene(scene, output=tmp_path / "f.exr", variant="llvm_ad_rgb")
    albedo = tree_albedo(tmp_path / "f.exr", scene.instances.id)
    c = np.array(leaf_colour(library.resolve("box")))
    expect = np.where((k == 0)[:, None], FLUSH, np.where((k == 1)[:, None], FLOWER, c))
    np.testing.assert_allclose(albedo, expect, rtol=0.03)


@pytest.mark.parametrize(
    ("accents", "fragment"),
    [
        ("[{ share = 0.7, colour = [0.2, 0.1, 0.1] }, { share = 0.5, colour = [0.3, 0.3, 0.0] }]", "add up to 1.2"),
        ("[{ share = 0.1, colour = [0.95, 0.1, 0.1] }]", "at most 0.9"),
        ("[{ share = 0.1, colour = [0.2, 0.1, 0.1], amount = [0.9, 0.5] }]", "must not exceed"),
    ],
)
def test_bad_accents_are_one_line_naming_the_field(tmp_path: Path, accents: str, fragment: str):
    cfg = tmp_path / "scene.toml"
    cfg.write_text(f'[terrain]\nflat = {{}}\n[[species]]\nmodel = "broadleaf"\npercent = 50\naccents = {accents}\n')
    out = tmp_path / "t.npz"
    r = run_forest("scatter", cfg, "-o", out)
    assert r.returncode == 2, (r.stdout, r.stderr)
    line = r.stderr.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in line
    assert "scene.toml" in line and "species[0].accents" in line and fragment in line, line
    assert not out.exists()


def test_scalar_rgb_bins_give_accented_crowns_their_own_bins():
    """JitterBins: with the accent groups, each group has a bin of its own whose factor is its trees' mean
    (so a red crown stays red in scalar_rgb); without them the red crowns are averaged into green bins."""
    from forest.render.instancing import JitterBins
    from forest.tint import oklab

    n = 2000
    ids, species = np.arange(n) + 5, np.zeros(n, np.int64)
    acc = _accents()
    accents, _ = acc.draw(species, ids, 11)
    t = tree_tints(np.ones((n, 3), np.float32), species, ids, 11, BROADLEAF, [11.0], [0.18], acc).astype(np.float64)
    bins, factors = JitterBins(t, species, ids, BROADLEAF, accents=accents).bins(8)
    for j in (0, 1):
        group = accents == j
        assert len(set(bins[group].tolist())) == 1 and bins[group][0] == 6 + j  # the last two bins
        assert not np.isin(bins[~group], [6 + j]).any()
        np.testing.assert_allclose(factors[0, 6 + j], t[group].mean(axis=0), rtol=1e-12)
    assert set(bins[accents < 0].tolist()) == set(range(6))

    def hue(rgb):
        lab = oklab(rgb)
        return np.degrees(np.arctan2(lab[:, 2], lab[:, 1]))

    red = hue(np.array([FLUSH]))[0]
    # With its own bin the flushing crowns' colour is red's hue; averaged into green bins no bin comes near it.
    assert abs(hue(BROADLEAF * factors[0, 6])[0] - red) < 10.0
    _, plain = JitterBins(t, species, ids, BROADLEAF).bins(8)
    assert np.min(np.abs(hue(BROADLEAF * plain[0]) - red)) > 60.0


def test_tree_accents_are_the_configs_draw_for_a_scattered_set_only(tmp_path):
    from test_scene import four_trees, make_config

    library = BoxLibrary(tmp_path / "lib")
    cfg = make_config(tmp_path).with_overrides(
        {"species[0].accents": [{"share": 0.5, "colour": list(FLUSH)}, {"share": 0.5, "colour": list(FLOWER)}]}
    )
    elsewhere = load_scene(cfg, four_trees(), library=library)
    assert elsewhere.tree_accents() is None  # its tints are its own, not this config's
    inst = four_trees()
    inst.meta["inputs"] = {}
    scene = load_scene(cfg, inst, library=library)
    k, _ = accent_table(model_settings(cfg)).draw(inst.species, inst.id, cfg.seed)
    np.testing.assert_array_equal(scene.tree_accents(), k)
    assert (k >= 0).all()


def test_a_clustered_accent_keeps_its_share_and_gathers_in_patches():
    """clustering = 1: about the same share over the terrain, but most of the accented trees in a fifth of it; the
    draw depends only on the tree and its place (a subset draws the same); clustering = 0 is the plain draw."""
    from forest.tint import Where

    n = 60_000
    rng = np.random.default_rng(4)
    pos = np.stack([rng.uniform(0, 1000, n), np.zeros(n), rng.uniform(0, 1000, n)], 1)
    ids, species = np.arange(n), np.zeros(n, np.int64)
    where = Where.of(pos, (0.0, 0.0, 1000.0, 1000.0))
    plain = _accents(shares=(0.05,), amounts=((1.0, 1.0),))
    patchy = dataclasses.replace(plain, clustering=np.array([[1.0]]), scale=np.array([[150.0]]))
    k0, _ = plain.draw(species, ids, 3, where)
    k1, _ = patchy.draw(species, ids, 3, where)
    assert abs((k1 == 0).mean() - 0.05) < 0.01  # the share is kept
    # Patches: the accented trees' neighbourhoods (50 m cells) are far more uneven than the plain draw's.
    cells = (pos[:, 0] // 50).astype(int) * 20 + (pos[:, 2] // 50).astype(int)

    def unevenness(k):
        counts = np.bincount(cells[k == 0], minlength=400)
        return counts.std() / counts.mean()

    assert unevenness(k1) > 2.5 * unevenness(k0)
    top = np.sort(np.bincount(cells[k1 == 0], minlength=400))[::-1]
    assert top[:80].sum() > 0.5 * top.sum()  # a fifth of the cells hold most of them
    sub = np.random.default_rng(5).permutation(n)[:3000]
    np.testing.assert_array_equal(patchy.draw(species[sub], ids[sub], 3, where.rows(sub))[0], k1[sub])
    with pytest.raises(ValueError, match="places"):
        patchy.draw(species, ids, 3)


def test_a_scatter_with_clustered_accents_is_the_scenes_retint(tmp_path):
    """The tints scatter writes for clustered accents are the ones the Scene recomputes (same places, same draw)."""
    from forest.scatter import scatter

    cfg = parse_config(
        '[terrain]\nflat = { size = 400.0 }\n[scatter]\ncount = 4000\n[[species]]\nmodel = "broadleaf"\npercent = 100\n'
        "accents = [{ share = 0.1, colour = [0.2, 0.09, 0.035], clustering = 1.0, patch_scale = 80.0 }]\n",
        path=tmp_path / "scene.toml",
        base_dir=tmp_path,
    )
    inst, _ = scatter(cfg)
    scene = load_scene(cfg, inst)
    assert scene.instances.tint.tobytes() == inst.tint.tobytes()
    k = scene.tree_accents()
    assert k is not None and 0.06 < (k == 0).mean() < 0.14
