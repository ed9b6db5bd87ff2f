"""Ground cover that reads as a meadow: patches (``clumping``) and a band along the presence edge (``edge``)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from conftest import write_png, write_scene

from forest.config import load_config
from forest.errors import ConfigError
from forest.scatter import scatter

SIZE = 100.0  # the flat terrain's side, metres, centred on the origin
CAMERA = "[camera]\nposition = [0.0, 1.7, 0.0]\ntarget = [0.0, 1.0, 30.0]\n"
#: Reaches every corner of the 100 m square at full density (0.7 · 110 = 77 m > 50√2 m).
COVER = 'model = "grass"\ndensity = 2.0\nmax_distance = 110.0\npresence = false\n'
COLUMNS = (
    "id",
    "position",
    "rotation",
    "yaw",
    "scale",
    "species",
    "tint",
    "partition",
    "normal",
    "phase",
    "individual",
)


def config(tmp_path, extra: str = "", *, seed: int = 5, maps: str = "", name: str = "scene.toml"):
    text = f"""
seed = {seed}
[terrain]
flat = {{ size = {SIZE} }}
{maps}
[scatter]
count = 10
[[species]]
model = "broadleaf"
percent = 100
{CAMERA}
[[ground_cover]]
{COVER}{extra}
"""
    return load_config(write_scene(tmp_path, text, name))


def cover_rows(cfg):
    inst, _ = scatter(cfg)
    return inst.subset(inst.species == 1)


def cell_counts(position: np.ndarray, cell: float = 5.0) -> np.ndarray:
    """Plants per ``cell`` × ``cell`` m square over the terrain, (SIZE/cell)² counts."""
    k = int(SIZE / cell)
    ix = np.clip(((position[:, 0] + SIZE / 2) // cell).astype(int), 0, k - 1)
    iz = np.clip(((position[:, 2] + SIZE / 2) // cell).astype(int), 0, k - 1)
    return np.bincount(ix * k + iz, minlength=k * k)


def digest(inst) -> str:
    h = hashlib.sha256()
    for c in COLUMNS:
        h.update(getattr(inst, c).tobytes())
    return h.hexdigest()


# -- patches --------------------------------------------------------------------------------------

#: sha256 over COLUMNS of the ground cover of ``config(tmp_path)``, as forest wrote it before
#: ``clumping`` and ``edge`` existed (computed with that code; the tint column follows the grass
#: preset's leaf colour, so it was recomputed when that colour changed, positions untouched).
GOLDEN = (20000, "565d7f4b49460fad4de3b4518859a2f16f3a0e30b0895dac9f04471cfc407aad")


def test_no_clumping_gives_the_plants_of_before_byte_for_byte(tmp_path):
    even = cover_rows(config(tmp_path))
    zero = cover_rows(config(tmp_path, "clumping = { strength = 0.0, scale = 3.0 }\n", name="zero.toml"))
    assert digest(zero) == digest(even)
    assert (len(even), digest(even)) == GOLDEN


def test_clumping_varies_the_density_in_patches_and_keeps_its_mean(tmp_path):
    even = cover_rows(config(tmp_path))
    clumped = cover_rows(config(tmp_path, "clumping = { strength = 0.8, scale = 12.0 }\n", name="c.toml"))
    expected = 2.0 * SIZE * SIZE
    assert len(even) == pytest.approx(expected, rel=0.03)
    assert len(clumped) == pytest.approx(expected, rel=0.05)
    a, b = cell_counts(even.position), cell_counts(clumped.position)
    # Even: Poisson counts (coefficient of variation 1/√50 ≈ 0.14); patches: about √(0.8² / 3) ≈ 0.46 more.
    cv_even, cv_clumped = a.std() / a.mean(), b.std() / b.mean()
    assert cv_even < 0.2 and cv_clumped > 2.0 * cv_even
    # The densest tenth of the cells holds well over twice what the thinnest tenth does.
    q = np.sort(b)
    assert q[-len(q) // 10 :].mean() > 2.5 * q[: len(q) // 10].mean()
    # Patches are patches: neighbouring cells are alike (correlated), not salt and pepper.
    g = b.reshape(20, 20).astype(float) - b.mean()
    assert (g[:, 1:] * g[:, :-1]).mean() / g.var() > 0.4


def test_clumping_size_makes_dense_patches_taller(tmp_path):
    extra = "scale = [1.0, 1.0]\nclumping = { strength = 0.8, scale = 12.0, size = 0.4 }\n"
    rows = cover_rows(config(tmp_path, extra))
    assert rows.scale.min() >= 0.6 - 1e-6 and rows.scale.max() <= 1.4 + 1e-6 and rows.scale.std() > 0.1
    counts = cell_counts(rows.position)
    k = int(SIZE / 5.0)
    cell = np.clip(((rows.position[:, 0] + SIZE / 2) // 5.0).astype(int), 0, k - 1) * k + np.clip(
        ((rows.position[:, 2] + SIZE / 2) // 5.0).astype(int), 0, k - 1
    )
    assert np.corrcoef(rows.scale, counts[cell])[0, 1] > 0.5


def test_same_seed_same_plants_another_seed_other_plants(tmp_path):
    extra = "clumping = { strength = 0.7, scale = 8.0, size = 0.2 }\n"
    a = cover_rows(config(tmp_path, extra, name="a.toml"))
    b = cover_rows(config(tmp_path, extra, name="b.toml"))
    c = cover_rows(config(tmp_path, extra, seed=6, name="c.toml"))
    assert digest(a) == digest(b) and digest(a) != digest(c)


def test_clumping_is_checked(tmp_path):
    with pytest.raises(ConfigError, match=r"ground_cover\[0\]\.clumping\.strength"):
        config(tmp_path, "clumping = { strength = 1.5 }\n")
    with pytest.raises(ConfigError, match=r"ground_cover\[0\]\.clumping"):
        config(tmp_path, "clumping = { strenght = 0.5 }\n", name="typo.toml")


# -- edge band ------------------------------------------------------------------------------------

RADIUS = 25.0  # the presence map's disc of trees, metres
PIXEL = SIZE / 128


def disc_map(tmp_path) -> str:
    c = (np.arange(128) + 0.5) * PIXEL - SIZE / 2
    z, x = np.meshgrid(c, c, indexing="ij")
    write_png(tmp_path / "presence.png", (np.hypot(x, z) <= RADIUS).astype(float))
    return '[maps]\npresence = "presence.png"\n'


def test_edge_keeps_plants_near_the_presence_edge_on_both_sides(tmp_path):
    rows = cover_rows(config(tmp_path, "edge = 6.0\n", maps=disc_map(tmp_path)))
    r = np.hypot(rows.position[:, 0], rows.position[:, 2])
    off = np.abs(r - RADIUS)
    # Only within the band (to a map pixel) …
    assert off.max() <= 6.0 + PIXEL
    # … on both sides, at the full density up to half its width: 2/m² over the ring |r − R| ≤ 2.5 m.
    inner = (r < RADIUS) & (off <= 2.5)
    outer = (r > RADIUS) & (off <= 2.5)
    ring_in = np.pi * (RADIUS**2 - (RADIUS - 2.5) ** 2)
    ring_out = np.pi * ((RADIUS + 2.5) ** 2 - RADIUS**2)
    assert inner.sum() == pytest.approx(2.0 * ring_in, rel=0.12)
    assert outer.sum() == pytest.approx(2.0 * ring_out, rel=0.12)
    # With presence = true, only the inner side.
    inside = cover_rows(
        config(tmp_path, "edge = 6.0\n", maps=disc_map(tmp_path), name="in.toml").with_overrides(
            {"ground_cover[0].presence": True}
        )
    )
    r_in = np.hypot(inside.position[:, 0], inside.position[:, 2])
    assert len(inside) > 0 and r_in.max() <= RADIUS + PIXEL and (RADIUS - r_in).max() <= 6.0 + PIXEL


def test_edge_needs_a_presence_map(tmp_path):
    with pytest.raises(ConfigError, match=r"ground_cover\[0\]\.edge"):
        cover_rows(config(tmp_path, "edge = 6.0\n"))
