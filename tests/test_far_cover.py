"""Woods and open ground on the far landscape (forest.far_cover; ``[render] horizon_hills``' ``woods``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_render import trees

from forest.config import parse_config
from forest.far_cover import CROWN_DEPTH, CROWN_M, TEXELS, FarCover, cover_tile, crown_domes, far_cover
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


def test_forest_path_draws_the_mosaic_the_host_computes(tmp_path, monkeypatch):
    """Looking down at the skirt from 40 m (a pixel ≈ 0.7 m, the tile's texels 4 m) where the mosaic has an edge
    between woods and open ground, the first-hit albedo with woods is the one without times the mosaic's factor
    at the pixel's world position, as :class:`FarCover` computes it on the host (the ground's detail texture,
    the same in both, cancels).  The woods' relief is left out here (the same ground in both), and tested
    below."""
    import forest.skirt

    skirt_mesh = forest.skirt.skirt_mesh
    monkeypatch.setattr(forest.skirt, "skirt_mesh", lambda t, r, h=None, *rest: skirt_mesh(t, r, h))
    library = BoxLibrary(tmp_path / "lib")
    rng = np.random.default_rng(1)
    # A wood on the west half and open ground on the east: the two kinds of land the mosaic draws.
    xz = np.stack([rng.uniform(-45.0, 0.0, 300), rng.uniform(-45.0, 45.0, 300)], axis=1)
    positions = np.stack([xz[:, 0], np.zeros(300), xz[:, 1]], axis=1)

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


def test_the_woods_stand_a_canopy_high_with_crowns_on_top():
    """The relief Δy = s(d/P)·C·H·(1 − a_c + a_c·k): none on the terrain or on open ground; on the woods between
    (1 − a_c)·H and H, crowns spaced about CROWN_M apart along a line through them."""
    fc = far_cover((0.05, 0.07, 0.03), (0.03, 0.05, 0.01), 0.6, (-50.0, -50.0, 50.0, 50.0), 10.0, 2, height=20.0)
    assert fc is not None and fc.height == 20.0
    k = (np.arange(TEXELS) + 0.5) / TEXELS * fc.tile_m
    x, z = np.meshgrid(k + 1000.0 * fc.tile_m, k)
    woods = fc.woods(x, z)
    relief = fc.relief(x, z)
    np.testing.assert_allclose(woods, 1.0 - fc.tile[..., 0], atol=1e-6)  # at texel centres: the tile's C
    open_ground = woods < 0.01
    assert open_ground.mean() > 0.1 and float(relief[open_ground].max()) <= 0.01 * 20.0  # open ground stays down
    deep = woods > 1.0 - 1e-6
    assert float(relief[deep].min()) >= (1.0 - CROWN_DEPTH) * 20.0 - 1e-4 and float(relief[deep].max()) <= 20.0
    assert float(relief[deep].std()) > 1.0  # crowns, not a flat table
    assert np.all(fc.relief(np.array([0.0, 49.9]), np.array([0.0, -49.9])) == 0.0)  # on the terrain
    # Along a 2 km line through the woods (1 m steps) the crowns' tops: one per CROWN_M-ish stretch.
    row = int(np.argmax(deep.mean(axis=1)))
    line_x = np.arange(0.0, 2000.0, 1.0) + 1000.0 * fc.tile_m
    line_z = np.full_like(line_x, k[row])
    domes = crown_domes(line_x, line_z, 2)
    tops = int(np.sum((domes[1:-1] > domes[:-2]) & (domes[1:-1] >= domes[2:]) & (domes[1:-1] > 0.3)))
    assert 2000.0 / (3.0 * CROWN_M) < tops < 2000.0 / (0.5 * CROWN_M)
    assert np.array_equal(crown_domes(line_x, line_z, 2), domes) and not np.array_equal(
        crown_domes(line_x, line_z, 3), domes
    )
    # No canopy height, no relief.
    flat = far_cover((0.05, 0.07, 0.03), (0.03, 0.05, 0.01), 0.6, (-50.0, -50.0, 50.0, 50.0), 10.0, 2)
    assert flat is not None and float(np.abs(flat.relief(x, z)).max()) == 0.0


def test_the_relief_is_averaged_over_the_spacing_of_the_mesh_that_carries_it():
    """Prefilter: up to a crown's spacing the relief is the unfiltered one; averaged over 256 m (a far ring's
    spacing) the crowns go (in deep woods the relief is nearly flat) while the woods' mean height stays; and along an arc
    of such a ring, neighbouring columns a few metres apart no longer jump by a crown's depth (the jumps that,
    interpolated to the next ring, drew ridges)."""
    from forest.far_cover import dome_mean

    fc = far_cover((0.05, 0.07, 0.03), (0.03, 0.05, 0.01), 0.6, (-50.0, -50.0, 50.0, 50.0), 10.0, 2, height=20.0)
    assert fc is not None
    rng = np.random.default_rng(4)
    x, z = rng.uniform(0.0, fc.tile_m, (2, 200_000)) + 7.0 * fc.tile_m
    sharp = fc.relief(x, z)
    np.testing.assert_allclose(fc.relief(x, z, 2.0), sharp, atol=1e-9)
    wide = fc.relief(x, z, 256.0)
    assert float(wide.mean()) == pytest.approx(float(sharp.mean()), rel=0.02)
    deep = fc.woods(x, z) > 0.999
    assert deep.sum() > 1000
    assert float(wide[deep].std()) < 0.1 * float(sharp[deep].std())
    level = 20.0 * (1.0 - CROWN_DEPTH + CROWN_DEPTH * dome_mean())
    assert float(np.median(wide[deep])) == pytest.approx(level, rel=0.02)  # the crowns' mean height
    # An arc 8 km out, columns 5 m apart.
    phi = np.arange(4000) * (5.0 / 8000.0) + 0.3
    ax, az = 8000.0 * np.cos(phi) + 7.0 * fc.tile_m, 8000.0 * np.sin(phi)
    jumps = {f: np.abs(np.diff(fc.relief(ax, az, f))) for f in (None, 256.0)}
    p90 = {f: float(np.percentile(j, 90)) for f, j in jumps.items()}
    assert p90[None] > 0.05 * 20.0 and p90[256.0] < 0.15 * p90[None]  # measured 0.37 m against 3.1 m


def test_the_wooded_skirt_joins_the_terrain_and_is_fine_enough_for_crowns():
    """With woods the skirt still closes on the terrain's boundary (its open edges are the terrain's boundary
    and the outer ring), its rings' neighbours are at most RELIEF_STEP apart seen from the centre, it is the
    hills plus the relief, and its normals are the hills' (smooth) ones."""
    from forest.skirt import (
        HILL_RINGS,
        RELIEF_STEP,
        RELIEF_STEP_MAX,
        Hills,
        boundary_edges,
        relief_step,
        skirt_mesh,
        skirt_triangles,
    )
    from forest.terrain import fbm_heights, grid_terrain

    terrain = grid_terrain(fbm_heights(33, 4, 0.5, 1) * 20.0, (200.0, 200.0))
    fc = far_cover((0.05, 0.07, 0.03), (0.03, 0.05, 0.01), 0.6, terrain.extent, 20.0, 1, height=25.0)
    hills = Hills(300.0, 1000.0, 4)
    plain = skirt_mesh(terrain, 30_000.0, hills)
    wooded = skirt_mesh(terrain, 30_000.0, hills, fc)
    assert plain is not None and wooded is not None
    k = len(np.unique(boundary_edges(terrain.faces)))
    np.testing.assert_array_equal(wooded.vertices[:k], plain.vertices[:k])  # the terrain's boundary
    q = (len(wooded.vertices) - k) // (HILL_RINGS + 1)
    assert len(wooded.vertices) == k + (HILL_RINGS + 1) * q and q > 4 * k
    # Open edges: the terrain's boundary (same positions) and the outer ring.
    open_edges = boundary_edges(wooded.faces)
    assert len(open_edges) == len(boundary_edges(terrain.faces)) + q
    inner = {tuple(sorted(map(tuple, wooded.vertices[e].tolist()))) for e in open_edges if max(e) < k}
    terrain_v = np.asarray(terrain.vertices, np.float32)
    assert inner == {tuple(sorted(map(tuple, terrain_v[e].tolist()))) for e in boundary_edges(terrain.faces)}
    rings = wooded.vertices[k:].reshape(HILL_RINGS + 1, q, 3).astype(np.float64)
    ang = np.sort(np.arctan2(rings[5, :, 2], rings[5, :, 0]))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))
    assert float(gaps.max()) <= RELIEF_STEP * 1.01
    # A camera's step: 1.5 pixels, within the finest and coarsest.
    assert relief_step(50.0, 800) == pytest.approx(1.5 * np.radians(50.0) / 800)
    assert relief_step(50.0, 8000) == RELIEF_STEP and relief_step(90.0, 64) == RELIEF_STEP_MAX
    coarse = skirt_mesh(terrain, 30_000.0, hills, fc, relief_step(50.0, 800))
    assert coarse is not None and len(plain.vertices) < len(coarse.vertices) < len(wooded.vertices)
    # The pre-flight's count of the skirt's triangles, without building it, is what each build makes.
    flat = skirt_mesh(terrain, 30_000.0)
    assert flat is not None and skirt_triangles(terrain) == len(flat.faces)
    assert skirt_triangles(terrain, hills) == len(plain.faces)
    assert skirt_triangles(terrain, hills, True) == len(wooded.faces)
    assert skirt_triangles(terrain, hills, True, relief_step(50.0, 800)) == len(coarse.faces)
    # The first k columns of every ring are the plain hills' vertices, raised by the relief there.
    base = plain.vertices[k:].reshape(HILL_RINGS + 1, k, 3).astype(np.float64)
    np.testing.assert_allclose(rings[:, :k, [0, 2]], base[:, :, [0, 2]], atol=1e-3)
    lift = rings[1:, :k, 1] - base[1:, :, 1]
    centre = np.array([0.0, 0.0])  # the terrain's extent is centred on the origin
    radii = np.linalg.norm(base[:, :, [0, 2]] - centre, axis=-1)
    spacing = np.diff(radii, axis=0)  # each ring's relief is averaged over its spacing from the ring inside it
    np.testing.assert_allclose(lift, fc.relief(base[1:, :, 0], base[1:, :, 2], spacing), atol=2e-2)
    assert float(lift.max()) > 20.0 and float(lift.min()) > -2e-2
    # Smooth normals: the crowns tilt the faces, not the shading normal, which stays the hills' own.
    low = skirt_mesh(terrain, 30_000.0, hills, dataclasses.replace(fc, height=1e-6))  # same rings, no crowns
    assert low is not None
    np.testing.assert_array_equal(wooded.normals, low.normals)
    assert float(np.abs(wooded.vertices[:, 1] - low.vertices[:, 1]).max()) > 20.0
    f = wooded.faces.astype(np.int64)
    v = wooded.vertices.astype(np.float64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    face_up = face_n[:, 1] / np.linalg.norm(face_n, axis=1)
    assert float(np.percentile(face_up, 5)) < float(np.percentile(wooded.normals[k:, 1], 5)) - 0.1


#: The 100 m square seen from 2 m over its south edge at x = 30, looking north just above the horizon (the trees,
#: west of x = −20, stay out of the frame).
LEVEL = """
seed = 3
[terrain]
flat = { size = 100.0 }
[camera]
position = [30.0, 2.0, -49.0]
target = [30.0, 2.0, 1000.0]
fov = 40.0
[lights]
sun = { elevation = 40.0, azimuth = 160.0, irradiance = 3.0 }
sky = { radiance = 1.0, colour = [1.0, 1.0, 1.0] }
[render]
width = 64
height = 32
spp = 4
max_depth = 2
horizon_hills = { height = 100.0, scale = 1500.0, seed = 1 }
[[species]]
model = "box"
percent = 100
"""


def level_scene(tmp_path, text: str = LEVEL):
    """The scene of ``text`` (default :data:`LEVEL`) with 150 boxes 18 m tall west of x = −20 (a wood)."""
    rng = np.random.default_rng(2)
    xz = np.stack([rng.uniform(-48.0, -20.0, 150), rng.uniform(-48.0, 48.0, 150)], axis=1)
    positions = np.stack([xz[:, 0], np.zeros(150), xz[:, 1]], axis=1)
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    return load_scene(cfg, trees(positions, scale=3.0), library=BoxLibrary(tmp_path / "lib"))


def test_forest_path_stands_the_woods_on_the_skyline(tmp_path, monkeypatch):
    """Looking level over the edge, the woods' relief (18 m boxes: a canopy 18 m high) covers sky that the hills
    alone leave open, and never uncovers any; the pixels it covers are lit ground."""
    import forest.skirt

    scene = level_scene(tmp_path)
    fc = path_inputs(scene).far_cover
    assert fc is not None and abs(fc.height - 18.0) < 1e-9
    layers = {}
    skirt_mesh = forest.skirt.skirt_mesh
    for name in ("hills", "woods"):
        if name == "hills":
            monkeypatch.setattr(forest.skirt, "skirt_mesh", lambda t, r, h=None, *rest: skirt_mesh(t, r, h))
        else:
            monkeypatch.setattr(forest.skirt, "skirt_mesh", skirt_mesh)
        out = tmp_path / f"{name}.exr"
        render_scene(scene, output=out, variant="llvm_ad_rgb")
        layers[name] = read_exr_channels(out)[0]
    upper = slice(2, 16)  # rows above the horizon (row 16)
    a_hills, a_woods = layers["hills"]["A"][upper], layers["woods"]["A"][upper]
    assert float(a_woods.mean()) > float(a_hills.mean()) + 0.02
    gained = (a_woods > 0.99) & (a_hills < 0.01)
    assert gained.sum() >= 5 and not np.any((a_hills > 0.99) & (a_woods < 0.01))
    assert float(layers["woods"]["G"][upper][gained].min()) > 0.005


def test_the_preflight_counts_the_skirt_forest_path_builds(tmp_path, monkeypatch):
    """The pre-flight memory model counts the skirt's world-space triangles (0.1–1.5 M with hills and woods) with
    the merged ones: its count is what forest_path's geometry then builds beside the terrain, and a wider image
    (a finer relief step) counts more."""
    from forest.preflight import scene_render_estimate, world_triangles
    from forest.render.frame import FrameSize
    from forest.render.path import PathScene

    scene = level_scene(tmp_path)
    built = PathScene(path_inputs(scene), "llvm_ad_rgb")
    skirt = built.stats.world_triangles - len(scene.terrain.faces)
    assert skirt > 10 * len(scene.terrain.faces)
    assert world_triangles(scene, [1.0], 64) == skirt
    assert world_triangles(scene, [1.0], 1280) > skirt
    import forest.render.path.from_scene as from_scene

    monkeypatch.setattr(from_scene, "far_plan", lambda *a, **k: (0, 0))  # the box library's parts count no triangles
    size = FrameSize(64, 32, 4)
    with_skirt = scene_render_estimate(scene, "llvm_ad_rgb", [1.0], size)
    assert with_skirt.far_triangles >= skirt
    bare_scene = level_scene(tmp_path, LEVEL.replace("horizon_hills", "horizon_ground = false\n# "))
    bare = scene_render_estimate(bare_scene, "llvm_ad_rgb", [1.0], size)
    assert with_skirt.far_triangles - bare.far_triangles == skirt and with_skirt.memory > bare.memory


def test_a_treeline_ends_the_woods_and_a_rock_line_bares_the_ground():
    """Below the treeline the mosaic is the one without it; above it the woods are gone (cover and relief), the
    factor is the open ground's, and above the rock line it is the rock's; forest_path's drjit factor is the
    host's at every height."""

    from forest.far_cover import ROCK_BAND_M, TREELINE_BAND_M

    far, canopy, rock = np.array([0.05, 0.07, 0.03]), np.array([0.03, 0.05, 0.01]), np.array([0.22, 0.21, 0.19])
    args = (far, canopy, 0.8, (-50.0, -50.0, 50.0, 50.0), 10.0, 0)
    plain = far_cover(*args, height=20.0)
    alpine = far_cover(*args, height=20.0, treeline=600.0, rockline=900.0, rock=rock)
    assert plain is not None and alpine is not None
    rng = np.random.default_rng(4)
    x, z = rng.uniform(200.0, 2000.0, 500), rng.uniform(200.0, 2000.0, 500)  # past the ramp
    low, mid, high = (np.full(500, h) for h in (600.0 - TREELINE_BAND_M, 700.0, 900.0 + ROCK_BAND_M))
    np.testing.assert_array_equal(alpine.factor(x, z, low), plain.factor(x, z))
    np.testing.assert_array_equal(alpine.woods(x, z, low), plain.woods(x, z))
    assert plain.woods(x, z).mean() > 0.5
    np.testing.assert_array_equal(alpine.woods(x, z, mid), 0.0)
    np.testing.assert_array_equal(alpine.relief(x, z, y=mid), 0.0)
    np.testing.assert_allclose(alpine.factor(x, z, mid), np.broadcast_to(alpine.open, (500, 3)), rtol=1e-12)
    np.testing.assert_allclose(alpine.factor(x, z, high) * far, np.broadcast_to(rock, (500, 3)), rtol=1e-12)
    with pytest.raises(Exception, match="rockline"):
        parse_config(
            SCENE.format(woods="true", x=0, z=0, z1=1).replace(
                "woods = true", "woods = true, treeline = 500.0, rockline = 400.0"
            )
        )
    # drjit against numpy over the bands
    y = np.linspace(400.0, 1100.0, 500)
    np.testing.assert_allclose(drjit_factor(alpine, x, y, z), alpine.factor(x, z, y), rtol=2e-4, atol=1e-5)


def test_steep_faces_above_the_treeline_are_rock_and_level_ground_is_not():
    """Between the treeline and the rock line, open ground steeper than 45° is [ground]'s rock and ground
    gentler than 30° stays open ground; below the treeline a steep face stays wooded (the same factor as level
    ground); drjit's factor agrees with the host's over slopes and heights."""

    from forest.far_cover import STEEP_ROCK_DEG, TREELINE_BAND_M, steep_share

    far, canopy, rock = np.array([0.05, 0.07, 0.03]), np.array([0.03, 0.05, 0.01]), np.array([0.22, 0.21, 0.19])
    alpine = far_cover(far, canopy, 0.8, (-50.0, -50.0, 50.0, 50.0), 10.0, 0, 20.0, 600.0, 900.0, rock)
    assert alpine is not None
    rng = np.random.default_rng(5)
    x, z = rng.uniform(200.0, 2000.0, 400), rng.uniform(200.0, 2000.0, 400)
    mid, low = np.full(400, 700.0), np.full(400, 600.0 - TREELINE_BAND_M)
    gentle, steep = np.cos(np.radians(STEEP_ROCK_DEG[0] - 1.0)), np.cos(np.radians(STEEP_ROCK_DEG[1] + 1.0))
    np.testing.assert_array_equal(steep_share(np.array([1.0, gentle, steep])), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(alpine.factor(x, z, mid, np.full(400, steep)) * far, np.broadcast_to(rock, (400, 3)))
    np.testing.assert_array_equal(alpine.factor(x, z, mid, np.full(400, gentle)), alpine.factor(x, z, mid))
    np.testing.assert_array_equal(alpine.factor(x, z, low, np.full(400, steep)), alpine.factor(x, z, low))
    # drjit against numpy: heights through both bands, slopes from level to vertical (either facing)
    y = np.linspace(400.0, 1100.0, 400)
    up = rng.uniform(-1.0, 1.0, 400)
    np.testing.assert_allclose(drjit_factor(alpine, x, y, z, up), alpine.factor(x, z, y, up), rtol=2e-4, atol=1e-5)


def test_a_snow_line_covers_the_land_above_it_but_not_faces_too_steep_to_hold_snow():
    """Above the snow line the factor is [ground]'s snow over woods, open ground and rock alike; a face steeper
    than 60° stays what it was below the snow; below the band nothing changes to the bit; forest_path's drjit
    factor agrees with the host's over heights and slopes; no snow line, no snow."""

    from forest.far_cover import SNOW_BAND_M, STEEP_SNOW_DEG

    far, canopy = np.array([0.05, 0.07, 0.03]), np.array([0.03, 0.05, 0.01])
    rock, snow = np.array([0.22, 0.21, 0.19]), np.array([0.85, 0.87, 0.90])
    args = (far, canopy, 0.8, (-50.0, -50.0, 50.0, 50.0), 10.0, 0, 20.0, 600.0, 900.0, rock)
    bare = far_cover(*args)
    snowy = far_cover(*args, snowline=1000.0, snow=snow)
    assert bare is not None and snowy is not None and far_cover(*args, snow=snow).snow is None  # type: ignore[union-attr]
    rng = np.random.default_rng(6)
    x, z = rng.uniform(200.0, 2000.0, 400), rng.uniform(200.0, 2000.0, 400)
    flat, cliff = np.ones(400), np.full(400, np.cos(np.radians(STEEP_SNOW_DEG[1] + 1.0)))
    for y in (np.full(400, 700.0), np.full(400, 1000.0 - SNOW_BAND_M)):  # open ground, and rock, under the band
        np.testing.assert_array_equal(snowy.factor(x, z, y, flat), bare.factor(x, z, y, flat))
    high = np.full(400, 1000.0 + SNOW_BAND_M)
    np.testing.assert_allclose(snowy.factor(x, z, high, flat) * far, np.broadcast_to(snow, (400, 3)), rtol=1e-12)
    np.testing.assert_allclose(snowy.factor(x, z, high) * far, np.broadcast_to(snow, (400, 3)), rtol=1e-12)
    np.testing.assert_array_equal(snowy.factor(x, z, high, cliff), bare.factor(x, z, high, cliff))
    np.testing.assert_allclose(bare.factor(x, z, high, cliff) * far, np.broadcast_to(rock, (400, 3)), rtol=1e-12)
    y = np.linspace(500.0, 1200.0, 400)
    up = rng.uniform(-1.0, 1.0, 400)
    np.testing.assert_allclose(drjit_factor(snowy, x, y, z, up), snowy.factor(x, z, y, up), rtol=2e-4, atol=1e-5)


def drjit_factor(fc, x: np.ndarray, y: np.ndarray, z: np.ndarray, up: np.ndarray | None = None) -> np.ndarray:
    """forest_path's factor (``FarCoverArrays.factor`` in llvm_ad_rgb) at world points, as an (N, 3) array."""
    import drjit as dr

    from forest.render.path.materials import FarCoverArrays
    from forest.runtime import mitsuba

    mi = mitsuba("llvm_ad_rgb")
    p = mi.Point3f(x.astype(np.float32), y.astype(np.float32), z.astype(np.float32))
    got = FarCoverArrays.build(mi, fc).factor(mi, p, True, None if up is None else mi.Float(up.astype(np.float32)))
    return np.stack([np.asarray(dr.detach(c)) for c in (got[0], got[1], got[2])], axis=1)
