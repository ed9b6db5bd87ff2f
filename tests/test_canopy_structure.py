"""Canopy structure: stands and clearings, emergents, snags, per-tree colour jitter; seeded and switchable."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_forest, write_scene

from forest.config import load_config
from forest.library import open_library
from forest.scatter import scatter
from forest.scatter.canopy import snag, stand_field, stand_keep
from forest.scatter.models import resolve_individuals, resolve_models
from forest.tint import jitter_colours

OFF = """
clumping = { strength = 0.0, clearings = 0.0 }
emergents = { fraction = 0.0 }
"""


def _scene(tmp_path, scatter_extra="", species_extra="", count=40000, seed=3, name="scene.toml", scale="[1.0, 1.0]"):
    return write_scene(
        tmp_path,
        f"""
        seed = {seed}
        [terrain]
        procedural = {{ size = 400.0, height = 0.0, resolution = 16 }}
        [scatter]
        count = {count}
        {scatter_extra}
        [[species]]
        model = "broadleaf"
        percent = 100
        scale = {scale}
        {species_extra}
        """,
        name=name,
    )


def _quadrats(inst, cells=40, size=400.0):
    x, z = inst.position[:, 0], inst.position[:, 2]
    h, _, _ = np.histogram2d(x, z, bins=cells, range=[[-size / 2, size / 2]] * 2)
    return h


@pytest.fixture(scope="module")
def library():
    return open_library()


def test_clearings_cover_the_set_share_of_the_area(tmp_path, library):
    cfg = _scene(tmp_path, "clumping = { scale = 60.0, strength = 0.0, clearings = 0.1 }", count=160000)
    q = _quadrats(inst := scatter(load_config(cfg))[0], cells=80)  # 5 m cells, ~25 candidates each
    empty = (q == 0).mean()  # an empty cell lies in a clearing, not by chance (P ≈ e⁻²⁵); cells on an edge are not
    assert len(inst) < 160000 * 0.92 and 0.06 <= empty <= 0.12, empty
    # The field itself: its area rank is uniform, so p = 0 on exactly the share c.
    f = stand_field((-200, -200, 200, 200), 60.0, 3)
    assert (stand_keep(f.rank, 0.0, 0.1) == 0).mean() == pytest.approx(0.1, abs=0.002)


def test_clumping_raises_the_variance_of_local_density(tmp_path, library):
    on, _ = scatter(load_config(_scene(tmp_path, "clumping = { scale = 50.0, strength = 0.8, clearings = 0.0 }")))
    off, _ = scatter(load_config(_scene(tmp_path, OFF, name="off.toml")))
    vmr = [q.var() / q.mean() for q in (_quadrats(on), _quadrats(off))]
    assert vmr[0] > 2.0 and 0.8 < vmr[1] < 1.2, vmr
    # Mean kept share for c = 0: ∫ min(1, 1 − s + 2sU) dU = 1 − s/4.
    assert len(on) / len(off) == pytest.approx(1 - 0.8 / 4, abs=0.02)


def test_emergents_form_a_tail_of_the_scale_distribution(tmp_path, library):
    cfg = _scene(tmp_path, "emergents = { fraction = 0.03, scale = [1.3, 1.6] }\nclumping = { strength = 0.0 }")
    inst, _ = scatter(load_config(cfg))
    tall = inst.scale > 1.0 + 1e-6
    assert tall.mean() == pytest.approx(0.03, abs=0.005)
    assert inst.scale[tall].min() >= 1.3 - 1e-6 and inst.scale.max() <= 1.6 + 1e-6
    assert np.allclose(inst.scale[~tall], 1.0)


def test_snags_are_the_tree_without_its_leaves(tmp_path, library):
    cfg = load_config(_scene(tmp_path, OFF, "dead = 0.05\nindividuals = 2", count=20000))
    inst, _ = scatter(cfg)
    assert (inst.individual >= 2).mean() == pytest.approx(0.05, abs=0.01)
    species = resolve_models(cfg, library)
    ind = resolve_individuals(cfg, library, species)[0]
    assert len(ind) == 4 and all("(snag)" in sp.name for sp in ind[2:])
    for lod in ind[2].lods:
        assert lod.parts and all(p.kind != "leaf" for p in lod.parts), lod.name
    assert snag(ind[0]).hash != ind[0].hash
    # Off: no snag rows and no snag individuals.
    off = load_config(_scene(tmp_path, OFF, "dead = 0.0\nindividuals = 2", count=2000, name="off.toml"))
    assert scatter(off)[0].individual.max() < 2
    assert len(resolve_individuals(off, library, resolve_models(off, library))[0]) == 2


def test_colour_jitter_spread_matches_the_setting(tmp_path, library):
    cfg = load_config(_scene(tmp_path, OFF, "colour_jitter = { hue = 12.0, value = 0.2 }", count=20000))
    inst, _ = scatter(cfg)
    base = np.array(species_leaf(cfg, library))
    leaf = inst.tint.astype(np.float64) * base
    # Undo the jitter's Oklab steps: hue angle and lightness relative to the base colour.
    lab = _oklab(leaf)
    lab0 = _oklab(base[None])[0]
    dh = np.degrees(np.angle((lab[:, 1] + 1j * lab[:, 2]) / (lab0[1] + 1j * lab0[2])))
    dv = lab[:, 0] / lab0[0] - 1
    assert np.abs(dh).max() == pytest.approx(12.0, abs=0.3) and np.std(dh) == pytest.approx(12 / np.sqrt(3), rel=0.05)
    assert np.abs(dv).max() == pytest.approx(0.2, abs=0.01) and np.std(dv) == pytest.approx(0.2 / np.sqrt(3), rel=0.05)
    # The defaults are the stronger jitter (±11°, ±18 %).
    assert load_config(_scene(tmp_path, name="d.toml")).species[0].colour_jitter.model_dump() == {
        "hue": 11.0,
        "value": 0.18,
    }


def species_leaf(cfg, library):
    from forest.tint import leaf_colour

    return leaf_colour(resolve_models(cfg, library)[0])


def _oklab(rgb):
    """Oklab of linear sRGB rows, by the same matrices :func:`forest.tint.jitter_colours` uses."""
    from forest.tint import _oklab_matrices, _rows

    to_lms, to_lab = _oklab_matrices()
    return _rows(to_lab, np.cbrt(_rows(to_lms, rgb)))


def test_jitter_round_trip_helper_is_exact():
    rgb = np.array([[0.1, 0.2, 0.03]])
    out = jitter_colours(rgb, np.array([10.0]), np.array([0.1]))
    a, b = _oklab(rgb)[0], _oklab(out)[0]
    assert np.degrees(np.angle((b[1] + 1j * b[2]) / (a[1] + 1j * a[2]))) == pytest.approx(10.0, abs=1e-6)


def test_same_seed_same_bytes_other_seed_other_structure(tmp_path, library):
    a, _ = scatter(load_config(_scene(tmp_path / "a", count=8000, species_extra="dead = 0.05")))
    b, _ = scatter(load_config(_scene(tmp_path / "b", count=8000, species_extra="dead = 0.05")))
    c, _ = scatter(load_config(_scene(tmp_path / "c", count=8000, species_extra="dead = 0.05", seed=4)))
    a.save(tmp_path / "a.npz")
    b.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    assert len(a) != len(c) or not np.array_equal(a.position, c.position)


def test_options_off_leave_the_scatter_as_before(tmp_path, library):
    """Off: every candidate of a flat, map-free terrain survives, scale is the stream's uniform, no snags."""
    from forest.scatter.candidates import random_streams

    cfg = load_config(_scene(tmp_path, OFF, "dead = 0.0", count=3000, scale="[0.5, 1.5]"))
    inst, _ = scatter(cfg)
    assert len(inst) == 3000
    xi = random_streams(cfg.seed)["scale"].random(3000)
    np.testing.assert_allclose(inst.scale, (0.5 + xi).astype(inst.scale.dtype), rtol=1e-6)


def _mixed(tmp_path, grouping: str, name: str):
    """Broadleaves 30 % and conifers 70 % on a flat 400 m square, every candidate kept (:data:`OFF`)."""
    return load_config(
        write_scene(
            tmp_path,
            f"""
            seed = 3
            [terrain]
            procedural = {{ size = 400.0, height = 0.0, resolution = 16 }}
            [scatter]
            count = 20000
            {OFF}
            {grouping}
            [[species]]
            model = "broadleaf"
            percent = 30
            [[species]]
            model = "conifer"
            percent = 70
            """,
            name=name,
        )
    )


def test_grouping_keeps_each_species_share_and_gathers_it_in_patches(tmp_path, library):
    """``[scatter] grouping``: the same sites, each species' share as its percent, but a tree's nearest neighbour is
    of its own species far more often than the independent draws' Σ p² = 0.3² + 0.7² = 0.58 (Pielou's segregation)."""
    from scipy.spatial import cKDTree

    mixed, _ = scatter(_mixed(tmp_path, "", "mixed.toml"))
    grouped, _ = scatter(_mixed(tmp_path, "grouping = { strength = 0.9, scale = 60.0 }", "grouped.toml"))
    np.testing.assert_array_equal(mixed.position, grouped.position)  # the sites are untouched
    same = {}
    for name, inst in (("mixed", mixed), ("grouped", grouped)):
        assert np.mean(inst.species == 1) == pytest.approx(0.7, abs=0.03)
        _, nn = cKDTree(inst.position[:, [0, 2]]).query(inst.position[:, [0, 2]], k=2)
        same[name] = float(np.mean(inst.species == inst.species[nn[:, 1]]))
    assert same["mixed"] == pytest.approx(0.58, abs=0.02)
    assert same["grouped"] > 0.8
    again, _ = scatter(_mixed(tmp_path, "grouping = { strength = 0.9, scale = 60.0 }", "again.toml"))
    np.testing.assert_array_equal(again.species, grouped.species)  # seeded


@pytest.mark.parametrize(
    "line, field",
    [
        ("clumping = { scale = -5.0 }", "scatter.clumping.scale"),
        ("clumping = { clearings = 1.5 }", "scatter.clumping.clearings"),
        ("clumping = { strength = 2.0 }", "scatter.clumping.strength"),
        ("emergents = { scale = [1.6, 1.3] }", "scatter.emergents.scale"),
        ("emergents = { fraction = -0.1 }", "scatter.emergents.fraction"),
        ("grouping = { strength = 1.5 }", "scatter.grouping.strength"),
        ("grouping = { scale = 0.0 }", "scatter.grouping.scale"),
    ],
)
def test_bad_values_fail_in_one_line(tmp_path, line, field):
    cfg = _scene(tmp_path, line, count=10)
    r = run_forest("scatter", cfg, "-o", tmp_path / "out.npz", "-q")
    err = r.stderr.strip()
    assert r.returncode == 2 and len(err.splitlines()) == 1 and field in err and "scene.toml" in err, err


def test_bad_dead_fails_in_one_line(tmp_path):
    cfg = _scene(tmp_path, "", "dead = 1.5", count=10)
    r = run_forest("scatter", cfg, "-o", tmp_path / "out.npz", "-q")
    err = r.stderr.strip()
    assert r.returncode == 2 and len(err.splitlines()) == 1 and "species[0].dead" in err, err


# -- edge taper ------------------------------------------------------------------------------------


def _half_plane_scene(tmp_path, taper: str, name: str = "scene.toml"):
    """Trees only where x ≥ 0 (a presence map whose right half is white): the edge is the line x = 0."""
    from conftest import write_png

    write_png(tmp_path / "presence.png", np.repeat((np.arange(64) >= 32)[None, :], 64, axis=0).astype(float))
    text = _scene(tmp_path, OFF + taper, count=20000, name=name).read_text()
    return write_scene(tmp_path, text + '\n[maps]\npresence = "presence.png"\n', name=name)


def test_edge_taper_scales_trees_by_their_distance_to_the_edge(tmp_path, library):
    """A straight edge at x = 0: a tree x metres inside is a + (1 − a)·smoothstep(0, W, x) times its size without
    the taper (the analytic distance, not the map's distance transform); the same trees, nothing else changed."""
    plain, _ = scatter(load_config(_half_plane_scene(tmp_path, "", name="plain.toml")))
    taper, _ = scatter(load_config(_half_plane_scene(tmp_path, "edge_taper = { width = 20.0, scale = 0.4 }")))
    assert np.array_equal(plain.id, taper.id) and np.array_equal(plain.position, taper.position)
    x = plain.position[:, 0].astype(np.float64)
    assert x.min() >= -1e-3 and (x < 20.0).sum() > 500
    t = np.clip(x / 20.0, 0.0, 1.0)
    expected = 0.4 + 0.6 * t * t * (3.0 - 2.0 * t)
    np.testing.assert_allclose(taper.scale / plain.scale, expected, atol=2e-4)
    assert np.array_equal(taper.scale[x >= 20.0], plain.scale[x >= 20.0])
    # The edge's envelope: trees within 2 m of it are under half the size of those 30 m in.
    assert taper.scale[x < 2.0].mean() < 0.5 * taper.scale[x > 30.0].mean()


def test_edge_taper_needs_a_presence_map(tmp_path):
    cfg = _scene(tmp_path, "edge_taper = { width = 20.0 }", count=10)
    r = run_forest("scatter", cfg, "-o", tmp_path / "out.npz", "-q")
    err = r.stderr.strip()
    assert r.returncode == 2 and len(err.splitlines()) == 1 and "scatter.edge_taper" in err, err
    assert "presence" in err and not (tmp_path / "out.npz").exists()
    bad = _scene(tmp_path, "edge_taper = { scale = 0.0 }", count=10, name="bad.toml")
    r = run_forest("scatter", bad, "-o", tmp_path / "out.npz", "-q")
    assert r.returncode == 2 and "scatter.edge_taper.scale" in r.stderr.strip(), r.stderr


def test_the_oklab_matrices_are_colour_sciences_to_the_bit():
    """forest keeps colour-science's Oklab matrices as constants (a scatter need not import colour-science):
    they are its M₁ · sRGB→XYZ and M₂, recomputed here, equal to the bit; and oklab() matches colour's own
    RGB → Oklab conversion of linear sRGB."""
    import colour
    from colour.models import oklab as ok

    from forest.tint import LMS_TO_LAB, SRGB_TO_LMS, oklab

    rgb_to_xyz = np.asarray(colour.models.RGB_COLOURSPACE_sRGB.matrix_RGB_to_XYZ, dtype=np.float64)
    np.testing.assert_array_equal(SRGB_TO_LMS, np.asarray(ok.MATRIX_1_XYZ_TO_LMS) @ rgb_to_xyz)
    np.testing.assert_array_equal(LMS_TO_LAB, np.asarray(ok.MATRIX_2_LMS_TO_LAB))
    rgb = np.random.default_rng(2).random((64, 3))
    want = colour.XYZ_to_Oklab(colour.RGB_to_XYZ(rgb, colour.models.RGB_COLOURSPACE_sRGB, apply_cctf_decoding=False))
    np.testing.assert_allclose(oklab(rgb), want, atol=1e-12)
