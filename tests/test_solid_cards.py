"""Solid cards (forest_path): cut-out leaf cards drawn as opaque cards of the same covered area.

The references are closed forms (a card whose texture covers a known share of it) and the cut-out
render of the same scene, which the solid one must match in coverage and colour while tracing fewer
ray segments.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_forest_path import forest_set, look

from forest.config import ForestError, parse_config
from forest.render.path import PathCamera, PathInputs, PathScene, SunLight
from forest.render.path.solid import barycentric_pattern, bilinear_repeat, modulation, solid_cards

from render_fixtures import BoxLibrary

VARIANT = "llvm_ad_rgb"


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("solidlib"))


def card_quad():
    """A 10×10 m quad at y = 5 (two triangles, uv over [0, 1]²) as the test library's card species draws it."""
    v = np.array([[-5, 5, -5], [5, 5, -5], [5, 5, 5], [-5, 5, 5]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.uint32)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return v, f, uv


def triangle_area(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    c = v[f]
    return 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)


def inside(p: np.ndarray, tri: np.ndarray) -> bool:
    """Whether point p lies in triangle ``tri`` (3, 3) (barycentric coordinates all ≥ 0, with slack)."""
    a, b, c = tri
    m = np.stack([b - a, c - a], axis=1)
    uv, *_ = np.linalg.lstsq(m, p - a, rcond=None)
    return bool(uv.min() >= -1e-5 and uv.sum() <= 1 + 1e-5)


def test_the_barycentric_pattern_covers_the_triangle_evenly():
    b = barycentric_pattern(8)
    assert b.shape == (64, 3)
    np.testing.assert_allclose(b.sum(axis=1), 1.0)
    assert b.min() > 0.0  # strictly inside: cell centres
    np.testing.assert_allclose(b.mean(axis=0), 1 / 3, atol=0.01)  # its centroid is the triangle's


def test_bilinear_lookup_repeats_and_interpolates_between_texel_centres():
    img = np.zeros((2, 2, 1), np.float32)
    img[0, 1, 0] = 1.0  # top row, right texel
    assert bilinear_repeat(img, np.array([0.75, 0.25]))[0] == pytest.approx(1.0)  # its centre
    assert bilinear_repeat(img, np.array([0.5, 0.25]))[0] == pytest.approx(0.5)  # half-way to its left neighbour
    assert bilinear_repeat(img, np.array([1.75, -0.75]))[0] == pytest.approx(1.0)  # repeats like the atlas


def test_a_half_covered_card_keeps_half_its_area_inside_itself_on_the_covered_side():
    v, f, uv = card_quad()
    rgba = np.ones((16, 16, 4), np.float32)
    rgba[..., :3] = (0.5, 0.6, 0.7)
    rgba[:, :8, 3] = 0.0  # alpha 0 where u < ½ (x < 0)
    sm = solid_cards(v, f, uv, None, rgba)
    area_in, area_out = triangle_area(v, f).sum(), triangle_area(sm.vertices, sm.faces).sum()
    assert sm.coverage == pytest.approx(0.5, abs=0.02)
    assert area_out == pytest.approx(area_in * sm.coverage, rel=1e-5)  # the covered area, exactly
    np.testing.assert_allclose(sm.rgb, (0.5, 0.6, 0.7), atol=1e-5)  # the covered texels' colour
    for k, tri in enumerate(sm.vertices.reshape(-1, 3, 3)):
        assert all(inside(p, v[f[k]]) for p in tri)  # each sheet stays within its card triangle
        assert tri[:, 0].mean() > v[f[k]][:, 0].mean()  # ... and moves towards the covered half (+X)
    np.testing.assert_allclose(sm.vertices[:, 1], 5.0)  # in the card's plane


def test_a_fully_transparent_card_leaves_no_triangles():
    v, f, uv = card_quad()
    rgba = np.ones((4, 4, 4), np.float32)
    rgba[..., 3] = 0.0
    sm = solid_cards(v, f, uv, None, rgba)
    assert len(sm.faces) == 0 and sm.coverage == 0.0


def test_only_plain_modulation_textures_are_drawn_solid():
    white = np.ones((8, 8, 4), np.float32)
    white[:, :4, 3] = 0.0
    assert modulation(white)  # a leaf cluster: white where covered, cut out elsewhere
    opaque = np.ones((8, 8, 4), np.float32)
    assert not modulation(opaque)  # nothing to cut out
    impostor = white.copy()
    impostor[:4, 4:, :3] = (0.35, 0.2, 0.1)  # bark below leaves: one colour per card would lose it
    impostor[4:, 4:, :3] = (0.1, 0.4, 0.1)
    assert not modulation(impostor)


def test_solid_cards_render_the_cut_out_cards_coverage_and_colour_with_fewer_segments(library):
    """A field of the test library's half cut-out cards seen from above under a sun: drawn solid they cover
    the same share of the frame with the same colour, and paths no longer restart past their gaps."""
    rng = np.random.default_rng(4)
    n = 80
    pos = np.zeros((n, 3), np.float32)
    pos[:, [0, 2]] = rng.uniform(-25.0, 25.0, size=(n, 2))
    pos[:, 1] = rng.uniform(0.0, 6.0, size=n)  # stacked at different heights: rays pass several gaps
    inst = forest_set(pos, np.ones(n, np.int64))
    camera = PathCamera(look([0.0, 120.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 30.0, 48, 48)
    base = PathInputs(
        instances=inst,
        species=[library.resolve("box"), library.resolve("card")],
        levels=np.zeros(n, np.int64),
        matrices=inst.matrices(),
        camera=camera,
        sun=SunLight((0.3, 1.0, 0.2), (1.0, 1.0, 1.0)),
        spp=32,
        max_depth=3,
    )
    out = {}
    for name, solid in (("cut", None), ("solid", np.ones(n, bool))):
        scene = PathScene(replace(base, solid=solid), VARIANT)
        passes = list(scene.passes(spp=32, seed=1, aux=True))
        spp = sum(p.spp for p in passes)
        rgb = sum(p.rgb for p in passes) / spp
        alpha = sum(p.alpha for p in passes) / spp
        segments = np.mean([p.segments.mean() for p in passes])
        out[name] = (rgb, alpha, segments, scene.stats)
    (rgb_c, a_c, seg_c, st_c), (rgb_s, a_s, seg_s, st_s) = out["cut"], out["solid"]
    assert st_s.instanced_triangles == st_c.instanced_triangles  # the same triangles, shrunk
    assert 0.15 < a_c.mean() < 0.85  # the frame is partly cards, partly the sky through their gaps
    assert a_s.mean() == pytest.approx(a_c.mean(), rel=0.05)  # the same coverage
    np.testing.assert_allclose(rgb_s.mean(axis=0), rgb_c.mean(axis=0), rtol=0.05)  # and colour
    assert seg_s < 0.8 * seg_c  # without the restarts past cut-out texels


MINIMAL = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 50\n'


def test_the_setting_reads_from_lod_and_refuses_negative_sizes():
    assert parse_config(MINIMAL).lod.solid_pixels == 80.0  # the default: trees up to 80 px tall
    assert parse_config(MINIMAL + "[lod]\nsolid_pixels = 0\n").lod.solid_pixels == 0.0  # off
    with pytest.raises(ForestError, match=r"solid_pixels"):
        parse_config(MINIMAL + "[lod]\nsolid_pixels = -5.0\n")


def test_a_scene_rebuilt_with_other_solid_flags_draws_them(library):
    """PathScene.pose takes per-tree solid flags (a new frame's): the same trees as cut cards or as sheets."""
    inst = forest_set([[0.0, 0.0, 0.0], [12.0, 0.0, 0.0]], [1, 1])
    camera = PathCamera(look([0.0, 100.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 30.0, 16, 16)
    inputs = PathInputs(
        instances=inst,
        species=[library.resolve("box"), library.resolve("card")],
        levels=np.zeros(2, np.int64),
        matrices=inst.matrices(),
        camera=camera,
    )
    scene = PathScene(inputs, VARIANT)
    cut = scene.geometry.parts.n_faces
    scene.pose(solid=np.array([False, True]))
    keys = sorted(scene.geometry.prototypes)
    assert keys == [(1, 0, 0, 0), (1, 0, 0, 1)]  # one prototype each way
    assert scene.geometry.parts.n_faces == cut + 2  # the solid card's two sheets added
    with pytest.raises(ForestError, match="solid"):
        scene.pose(solid=np.array([True]))
    # A level with nothing to draw solid (the box: no texture) shares its cut-out prototype, parts and all.
    box = scene.geometry.prototype(0, 0, 0, False)
    assert scene.geometry.prototype(0, 0, 0, True) is box


def _card_files(folder, covered_from: int = 8):
    """A card mesh (PLY) and its texture (PNG, alpha 0 where u < covered_from / 16) as a library part has them."""
    from forest.library.mesh import MeshData, write_ply
    from forest.library.textures import write_texture

    v, f, uv = card_quad()
    normals = np.tile(np.array([0.0, 1.0, 0.0], np.float32), (len(v), 1))
    mesh = write_ply(folder / "card.ply", MeshData(v, f, normals, uv))
    rgba = np.ones((16, 16, 4), np.float32)
    rgba[..., :3] = (0.5, 0.6, 0.7)
    rgba[:, :covered_from, 3] = 0.0
    return mesh, write_texture(folder / "card.png", rgba)


def test_solid_meshes_are_kept_in_the_cache_folder_and_read_back_the_same(tmp_path, monkeypatch):
    """A part's solid mesh is computed once, kept under forest's cache folder, and a later process reads the same
    arrays from it; a changed texture is another entry; an entry that is not a solid mesh is computed again."""
    import forest.render.path.solid as solid

    monkeypatch.setenv("FOREST_CACHE_DIR", str(tmp_path / "cache"))
    mesh, tex = _card_files(tmp_path)
    solid._solid_file.cache_clear()
    computed = solid._solid_file(str(mesh), str(tex))
    entry = solid.cache_entry(mesh, tex)
    assert entry.parent == tmp_path / "cache" / "solid" and entry.is_file()
    assert computed.coverage == pytest.approx(0.5, abs=0.02)

    solid._solid_file.cache_clear()  # as a new process would
    monkeypatch.setattr(solid, "solid_cards", lambda *a: pytest.fail("read from the cache, not computed"))
    kept = solid._solid_file(str(mesh), str(tex))
    for name in ("vertices", "faces", "normals", "uv", "rgb"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(computed, name))
    assert kept.coverage == computed.coverage
    monkeypatch.undo()
    monkeypatch.setenv("FOREST_CACHE_DIR", str(tmp_path / "cache"))

    other = tmp_path / "other"
    other.mkdir()
    mesh2, tex2 = _card_files(other, covered_from=12)  # the same mesh, another texture
    assert solid.cache_entry(mesh2, tex2) != entry and solid.cache_entry(mesh2, tex) == entry

    entry.write_bytes(b"not an npz")  # a damaged entry: computed again, and rewritten
    solid._solid_file.cache_clear()
    again = solid._solid_file(str(mesh), str(tex))
    np.testing.assert_array_equal(again.vertices, computed.vertices)
    assert solid.read_entry(entry) is not None
    solid._solid_file.cache_clear()


def test_an_unwritable_cache_folder_only_means_computing_again(tmp_path, monkeypatch):
    import forest.render.path.solid as solid

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("FOREST_CACHE_DIR", str(blocker / "below"))  # a folder that cannot be made
    mesh, tex = _card_files(tmp_path)
    solid._solid_file.cache_clear()
    sm = solid._solid_file(str(mesh), str(tex))
    assert sm.coverage == pytest.approx(0.5, abs=0.02) and not (blocker / "below").exists()
    solid._solid_file.cache_clear()
