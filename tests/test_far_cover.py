"""Woods and open ground on the far landscape (forest.far_cover; ``[render] horizon_hills``' ``woods``)."""

from __future__ import annotations

import numpy as np
from test_render import trees

from forest.config import parse_config
from forest.far_cover import TEXELS, FarCover, cover_tile, far_cover
from forest.ground import wrapped_bilinear
from forest.images import read_exr_channels
from forest.render import render_scene
from forest.render.path.from_scene import path_inputs
from forest.scene import load_scene

from render_fixtures import BoxLibrary


def test_the_tile_keeps_the_cover_and_is_seamless():
    tile = cover_tile(0.7, 3)
    assert tile.shape == (TEXELS, TEXELS, 2) and tile.dtype == np.float32
    gaps, woods = tile[..., 0].astype(np.float64), tile[..., 1].astype(np.float64)
    assert abs((1.0 - gaps.mean()) - 0.7) < 1e-5  # ⟨C⟩ = c̄
    assert abs(woods.mean() - 0.7) < 1e-5  # ⟨C·g⟩ = c̄: the grain keeps the woods' mean
    assert gaps.min() >= 0.0 and gaps.max() <= 1.0 and woods.min() >= 0.0
    cover = 1.0 - gaps
    assert (cover < 0.05).mean() > 0.1 and (cover > 0.95).mean() > 0.4  # patches of open ground and of woods
    # The grain: inside the woods the canopy varies from texel to texel (crowns against their shadows).
    inside = cover > 0.999
    assert 0.2 < float(np.std(woods[inside])) < 0.6
    # Periodic: the step across the seam is like any step between neighbouring columns (no edge at the wrap).
    seam = np.abs(cover[:, 0] - cover[:, -1]).mean()
    step = np.abs(np.diff(cover, axis=1)).mean()
    assert seam < 2.0 * step
    assert cover_tile(0.7, 3).tobytes() == tile.tobytes()
    assert not np.array_equal(cover_tile(0.7, 4), tile)


def test_the_mosaic_averages_to_the_far_albedo_and_fades_in_past_the_edge():
    far, canopy, c = np.array([0.05, 0.07, 0.03]), np.array([0.03, 0.05, 0.01]), 0.8
    fc = far_cover(far, canopy, c, (-50.0, -50.0, 50.0, 50.0), 10.0, 0)
    assert isinstance(fc, FarCover)
    rho_o = np.asarray(fc.open) * far
    np.testing.assert_allclose((1 - c) * rho_o + c * np.asarray(fc.canopy) * far, far, rtol=1e-12)
    # Over a whole tile past the ramp, ρ_far·m averages to ρ_far (a tile of texel centres: exact up to rounding).
    k = (np.arange(TEXELS) + 0.5) / TEXELS * fc.tile_m
    x, z = np.meshgrid(k + 1000.0 * fc.tile_m, k)
    m = fc.factor(x, z)
    np.testing.assert_allclose((far * m).reshape(-1, 3).mean(axis=0), far, rtol=1e-4)
    assert m.min() < 0.8 and m.max() > 1.5  # woods darker, open ground brighter than the mean
    # On the terrain, 1; half-way through the ramp, s(½) = ½ of the way.
    np.testing.assert_array_equal(fc.factor(np.array([0.0, 49.0]), np.array([0.0, -49.0])), 1.0)
    x0 = 55.0  # 5 m past the edge at x = 50: t = ½
    m_half = fc.factor(np.array([x0]), np.array([0.0]))
    w = wrapped_bilinear(fc.tile, np.array([x0 / fc.tile_m]), np.array([0.0]))
    m_full = w[..., :1] * np.asarray(fc.open) + w[..., 1:2] * np.asarray(fc.canopy)
    np.testing.assert_allclose(m_half, 1.0 + 0.5 * (m_full - 1.0), rtol=1e-12)
    # Nothing to draw under no canopy or a closed one.
    assert far_cover(far, canopy, 0.0, (0, 0, 1, 1), 1.0, 0) is None
    assert far_cover(far, canopy, 1.0, (0, 0, 1, 1), 1.0, 0) is None


#: A 100 m flat square with boxes on it; the camera 40 m over the skirt's (low) hills at (x, z), looking down.
SCENE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[camera]
position = [{x}, 40.0, {z}]
target = [{x}, 0.0, {z1}]
fov = 40.0
[lights]
sun = {{ elevation = 60.0, azimuth = 160.0, irradiance = 3.0 }}
sky = {{ radiance = 1.0, colour = [1.0, 1.0, 1.0] }}
[render]
width = 40
height = 40
spp = 4
max_depth = 2
aovs = ["P", "albedo"]
horizon_hills = {{ height = 0.5, scale = 20000.0, woods = {woods} }}
[[species]]
model = "box"
percent = 100
"""


def test_forest_path_draws_the_mosaic_the_host_computes(tmp_path):
    """Looking down at the skirt from 40 m (a pixel ≈ 0.7 m, the tile's texels 4 m) where the mosaic has an edge
    between woods and open ground, the first-hit albedo with woods is the one without times the mosaic's factor
    at the pixel's world position, as :class:`FarCover` computes it on the host (the ground's detail texture,
    the same in both, cancels)."""
    library = BoxLibrary(tmp_path / "lib")
    rng = np.random.default_rng(1)
    xz = rng.uniform(-45.0, 45.0, (60, 2))
    positions = np.stack([xz[:, 0], np.zeros(60), xz[:, 1]], axis=1)

    def scene_at(woods: str, x: float, z: float):
        text = SCENE.format(woods=woods, x=x, z=z, z1=z + 1.0)
        cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
        return load_scene(cfg, trees(positions), library=library)

    fc = path_inputs(scene_at("true", 0.0, 600.0)).far_cover
    assert fc is not None
    # Where in the tile's second quarter (well past the terrain) the open-ground weight varies the most over 32 m.
    gaps = fc.tile[256:512, 256:512, 0].reshape(32, 8, 32, 8)
    i, j = np.unravel_index(np.argmax(np.ptp(gaps, axis=(1, 3))), (32, 32))
    texel = fc.tile_m / fc.tile.shape[0]
    x, z = (256 + 8 * j + 4) * texel, (256 + 8 * i + 4) * texel
    layers, scenes = {}, {}
    for woods in ("true", "false"):
        scenes[woods] = scene = scene_at(woods, x, z)
        out = tmp_path / f"{woods}.exr"
        render_scene(scene, output=out, variant="llvm_ad_rgb")
        layers[woods] = read_exr_channels(out)[0]
    assert 0.001 < scenes["true"].terrain_albedo.far_cover < 0.999
    assert path_inputs(scenes["false"]).far_cover is None
    on, off = layers["true"], layers["false"]
    a_on = np.stack([on[f"albedo.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
    a_off = np.stack([off[f"albedo.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
    np.testing.assert_array_equal(on["P.X"], off["P.X"])  # the same ground
    expected = fc.factor(on["P.X"].astype(np.float64), on["P.Z"].astype(np.float64))
    assert float(np.ptp(expected[..., 1])) > 0.5  # the frame sees woods and open ground, not one value
    # A pixel averages its samples' factors (and the detail texture weights them): equal to the factor at its
    # mean position up to the texture's curvature within a pixel.
    rel = np.abs(a_on / a_off / expected - 1.0)
    assert float(np.median(rel)) < 0.005 and float(np.percentile(rel, 99)) < 0.03 and float(rel.max()) < 0.06
