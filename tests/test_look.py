"""The scene's look as data: individuals, per-tree colour jitter, the colour map as a tint of mean 1, ground cover."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

from forest.config import load_config
from forest.instances import COLUMNS, InstanceSet
from forest.scatter import scatter, scatter_models

SPECIES = """
[[species]]
model = "broadleaf"
percent = 60
[[species]]
model = "conifer"
percent = 30
individuals = 2
"""


def flat(tmp_path, extra: str = "", species: str = SPECIES, count: int = 3000, name: str = "scene.toml"):
    return load_config(
        write_scene(
            tmp_path,
            f"""
            seed = 5
            [terrain]
            flat = {{ size = 100.0 }}
            [scatter]
            count = {count}
            """
            + species
            + extra,
            name,
        )
    )


# -- existing streams stay byte-identical ---------------------------------------------------------

GOLDEN_SCENE = """
seed = 11
[terrain]
procedural = { size = 200.0, height = 40.0, octaves = 4, resolution = 64 }
[maps]
density = "density.png"
colour = "colour.png"
partition = "part.png"
[partitions]
"#ff0000" = "near"
"#00ff00" = "far"
[scatter]
count = 6000
clumping = { strength = 0.0, clearings = 0.0 }  # the streams as they were before canopy structure
emergents = { fraction = 0.0 }
min_distance = 1.5
align_to_normal = 0.3
method = "METHOD"
[[species]]
model = "broadleaf"
percent = 40
scale = [0.8, 1.3]
slope_max = 30.0
partitions = ["near"]
[[species]]
model = "conifer"
percent = 35
scale = [0.9, 1.6]
altitude = [5.0, 40.0]
[[species]]
model = "tower"
percent = 10
yaw_step = 90.0
"""

#: sha256 over the columns id … phase, written by forest before the ``individual`` stream was appended.
GOLDEN = {
    "random": (1950, "c258be8d3f98b6d642f73c0408351a557e1dd52739e9ed55b09f9824ccb83a5d"),
    "ecosystem": (274, "49824430278f35b1f0debc3ba1620013594d79103b4ce8ea917206803d236e34"),
}


@pytest.mark.parametrize("method", ["random", "ecosystem"])
def test_existing_streams_are_byte_identical(tmp_path, method):
    """Appending the individual stream left every earlier column as forest wrote it before, bit for bit."""
    y, x = np.mgrid[0:32, 0:32] / 31.0
    write_png(tmp_path / "density.png", 0.3 + 0.7 * x)
    write_png(tmp_path / "colour.png", np.stack([0.2 + 0.5 * x, 0.5 + 0.2 * y, 0.1 + 0 * x], 2))
    write_png(tmp_path / "part.png", np.stack([(y < 0.5), (y >= 0.5), 0 * y], 2).astype(float))
    cfg = load_config(write_scene(tmp_path, GOLDEN_SCENE.replace("METHOD", method), f"{method}.toml"))
    inst, _ = scatter(cfg)
    h = hashlib.sha256()
    for c in ("id", "position", "rotation", "yaw", "scale", "species", "partition", "normal", "phase"):
        h.update(getattr(inst, c).tobytes())
    assert (len(inst), h.hexdigest()) == GOLDEN[method]


# -- individuals -----------------------------------------------------------------------------------


def test_individuals_are_drawn_per_tree_deterministically(tmp_path):
    cfg = flat(tmp_path)
    a, report = scatter(cfg)
    b, _ = scatter(cfg)
    np.testing.assert_array_equal(a.individual, b.individual)
    broad, con = a.species == 0, a.species == 1
    # broadleaf: 4 individuals by default, each about a quarter of the trees; conifer: the 2 it asks for.
    counts = np.bincount(a.individual[broad], minlength=4)
    assert len(counts) == 4 and (np.abs(counts / broad.sum() - 0.25) < 0.04).all()
    assert set(np.unique(a.individual[con])) == {0, 1}
    assert report.individuals == {"broadleaf": 4, "conifer": 2}
    assert any(line.strip() == "individuals: broadleaf 4, conifer 2" for line in report.lines())


def test_individual_count_does_not_move_trees(tmp_path):
    """Individuals come from their own stream: asking for more changes no position, yaw or scale."""
    a, _ = scatter(flat(tmp_path))
    b, _ = scatter(flat(tmp_path, species=SPECIES.replace("individuals = 2", "individuals = 7"), name="b.toml"))
    for col in ("id", "position", "yaw", "scale", "rotation", "species", "phase"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))
    assert b.individual[b.species == 1].max() == 6


def test_the_scene_resolves_individuals_and_folds_the_column(tmp_path):
    from forest.library import individual, open_library
    from forest.scene import load_scene

    lib = open_library()
    cfg = flat(tmp_path, count=400)
    inst, _ = scatter(cfg, library=lib)
    scene = load_scene(cfg, inst, library=lib)
    assert [len(i) for i in scene.individuals] == [4, 2]
    for s, ind in enumerate(scene.individuals):
        assert ind[0] is scene.species[s]
        assert len({sp.hash for sp in ind}) == len(ind)  # different trees, not clones
    assert scene.individuals[0][3].hash == individual(lib, "broadleaf", 3).hash
    # A config asking for fewer individuals than the set was scattered with folds k into range (k mod n).
    fewer = cfg.with_overrides({"species[0].individuals": 3})
    folded = load_scene(fewer, inst, library=lib)
    k = inst.individual[inst.species == 0].astype(int)
    np.testing.assert_array_equal(folded.instances.individual[inst.species == 0], k % 3)


def test_a_mesh_species_has_one_individual(tmp_path):
    from forest.scene import load_scene

    mesh = tmp_path / "tree.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 2 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\n")
    cfg = flat(tmp_path, species='[[species]]\nmodel = "tree.obj"\npercent = 50\n', count=200)
    inst, _ = scatter(cfg)
    assert (inst.individual == 0).all()
    assert [len(i) for i in load_scene(cfg, inst).individuals] == [1]


def test_individual_column_saves_loads_and_defaults_for_older_files(tmp_path):
    inst, _ = scatter(flat(tmp_path, count=500))
    path = inst.save(tmp_path / "trees.npz")
    back = InstanceSet.load(path)
    np.testing.assert_array_equal(back.individual, inst.individual)
    sub = back.subset(back.species == 1)
    np.testing.assert_array_equal(sub.individual, inst.individual[inst.species == 1])
    # A file written before the column existed: every other column, no "individual".
    import zipfile

    old = tmp_path / "old.npz"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(old, "w") as dst:
        for item in src.infolist():
            if item.filename != "individual.npy":
                dst.writestr(item, src.read(item))
    legacy = InstanceSet.load(old)
    assert legacy.individual.dtype == np.uint8 and (legacy.individual == 0).all() and len(legacy) == len(inst)
    assert "individual" in COLUMNS


# -- the colour map as a tint of mean 1 ------------------------------------------------------------


def _colour_scene(tmp_path, mode: str | None, jitter: str = "colour_jitter = { hue = 0.0, value = 0.0 }"):
    rng = np.random.default_rng(3)
    write_png(tmp_path / "colour.png", 0.1 + 0.5 * rng.random((12, 16, 3)))
    normalise = f'colour_normalise = "{mode}"\n' if mode else ""
    species = f'[[species]]\nmodel = "broadleaf"\npercent = 100\n{jitter}\n'
    return flat(tmp_path, f'[maps]\ncolour = "colour.png"\n{normalise}', species, 2000, f"{mode}.toml")


def test_colour_map_is_a_tint_of_mean_one(tmp_path):
    """By default each linear channel is divided by its mean over the map: the canopy's mean colour is the species'."""
    from forest.images import read_map_rgb
    from forest.scene import load_scene

    cfg = _colour_scene(tmp_path, None)
    raw = read_map_rgb(tmp_path / "colour.png")  # OpenImageIO + colour-science's sRGB decoding
    scene = load_scene(cfg)
    np.testing.assert_allclose(scene.colour.rgb.reshape(-1, 3).mean(axis=0), 1.0, rtol=1e-5)
    np.testing.assert_allclose(scene.colour.rgb, raw / raw.reshape(-1, 3).mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(scene.colour.divisor, raw.reshape(-1, 3).mean(axis=0), rtol=1e-6)
    # The trees' tints are the grid at their bases: their mean is near 1 as well (uniform over the map).
    assert np.abs(scene.instances.tint.mean(axis=0) - 1.0).max() < 0.05


def test_luminance_and_none_normalisation(tmp_path):
    import colour

    from forest.images import read_map_rgb
    from forest.scene import load_scene

    raw = None
    grids = {}
    for mode in ("luminance", "none"):
        cfg = _colour_scene(tmp_path, mode)
        raw = read_map_rgb(tmp_path / "colour.png")
        grids[mode] = load_scene(cfg).colour.rgb
    y = colour.sRGB_to_XYZ(raw.reshape(-1, 3), apply_cctf_decoding=False)[:, 1]
    lum = colour.sRGB_to_XYZ(grids["luminance"].reshape(-1, 3), apply_cctf_decoding=False)[:, 1]
    assert lum.mean() == pytest.approx(1.0, rel=1e-4)  # mean luminance 1 …
    np.testing.assert_allclose(grids["luminance"] * y.mean(), raw, rtol=1e-5)  # … one factor: the hue kept
    np.testing.assert_allclose(grids["none"], raw, rtol=1e-6)  # as painted


def test_scatter_tints_equal_the_scene_tints(tmp_path):
    """Scatter writes the tint column with the function the Scene applies: a scattered set is unchanged by it."""
    from forest.scene import load_scene

    cfg = _colour_scene(tmp_path, None, jitter="")
    inst, _ = scatter(cfg)
    scene = load_scene(cfg, inst)
    assert scene.instances.tint.tobytes() == inst.tint.tobytes()


# -- per-tree jitter --------------------------------------------------------------------------------


def _oklch(rgb: np.ndarray) -> np.ndarray:
    """(L, C, h°) of linear sRGB by colour-science's own conversions."""
    import colour

    lab = colour.XYZ_to_Oklab(colour.sRGB_to_XYZ(rgb, apply_cctf_decoding=False))
    return np.stack([lab[:, 0], np.hypot(lab[:, 1], lab[:, 2]), np.degrees(np.arctan2(lab[:, 2], lab[:, 1]))], 1)


def test_jitter_is_deterministic_per_tree_id_and_within_bounds():
    from forest.tint import tree_tints

    base = np.array([[0.097, 0.178, 0.027], [0.055, 0.106, 0.034]])  # broadleaf, conifer leaf albedos
    n = 5000
    ids = np.arange(n, dtype=np.uint64) * 7 + 3
    species = np.arange(n) % 2
    ones = np.ones((n, 3), np.float32)
    t = tree_tints(ones, species, ids, 9, base, [4.0, 10.0], [0.08, 0.2])
    # The same id gets the same jitter in any other set (a subset, another order).
    order = np.random.default_rng(1).permutation(n)[:700]
    again = tree_tints(ones[order], species[order], ids[order], 9, base, [4.0, 10.0], [0.08, 0.2])
    np.testing.assert_array_equal(again, t[order])
    assert not np.array_equal(tree_tints(ones, species, ids, 10, base, [4.0, 10.0], [0.08, 0.2]), t)  # seed
    # Within bounds in OkLCh, measured by colour-science: hue within ±amplitude, L within ±value, chroma kept.
    before = _oklch(base[species])
    after = _oklch(base[species] * t)
    dh = (after[:, 2] - before[:, 2] + 180.0) % 360.0 - 180.0
    amp_h = np.array([4.0, 10.0])[species]
    amp_v = np.array([0.08, 0.2])[species]
    inside = (base[species] * t).min(axis=1) > 1e-6  # not clipped at the gamut's edge
    assert inside.mean() > 0.99
    assert (np.abs(dh[inside]) <= amp_h[inside] + 1e-3).all()
    assert (np.abs(after[inside, 0] / before[inside, 0] - 1.0) <= amp_v[inside] + 1e-6).all()
    np.testing.assert_allclose(after[inside, 1], before[inside, 1], rtol=2e-3)
    # … and spread over the whole range, not a few values.
    assert np.abs(dh[species == 0]).max() > 3.5 and np.abs(dh[species == 1]).max() > 9.0
    assert len(np.unique(np.round(t, 5), axis=0)) > 0.9 * n


def test_no_jitter_keeps_the_map_tint_exactly():
    from forest.tint import tree_tints

    m = np.random.default_rng(2).random((50, 3)).astype(np.float32) + 0.5
    t = tree_tints(m, np.zeros(50), np.arange(50), 1, np.array([[0.1, 0.2, 0.03]]), [0.0], [0.0])
    assert t.tobytes() == m.tobytes()


# -- ground cover --------------------------------------------------------------------------------


COVER = """
[camera]
position = [10.0, 1.7, -20.0]
target = [10.0, 1.0, 20.0]
[[ground_cover]]
model = "grass"
density = 4.0
max_distance = 15.0
[[ground_cover]]
model = "fern"
density = 1.0
max_distance = 30.0
slope_max = 90.0
"""


def test_ground_cover_grows_near_the_camera_only(tmp_path):
    cfg = flat(tmp_path, COVER, count=2000)
    inst, report = scatter(cfg)
    names = scatter_models(cfg)
    assert names == ["broadleaf", "conifer", "grass", "fern"] == inst.species_names
    cam = np.array([10.0, 1.7, -20.0])
    trees = inst.species < 2
    assert trees.sum() == report.kept
    for s, (reach, density) in {2: (15.0, 4.0), 3: (30.0, 1.0)}.items():
        rows = inst.species == s
        d = np.linalg.norm(inst.position[rows] - cam, axis=1)
        assert d.max() <= reach + 1e-3
        # The full density per m² of ground up to 0.7 of the reach (the 100 m square holds the disc whole) …
        r = np.sqrt((0.7 * reach) ** 2 - 1.7**2)
        assert (d <= 0.7 * reach).sum() == pytest.approx(density * np.pi * r * r, rel=0.1)
        # … thinning out beyond it: the outer ring holds far fewer than at full density.
        outer = np.pi * (reach**2 - (0.7 * reach) ** 2)
        assert 0.2 * density * outer < (d > 0.7 * reach).sum() < 0.8 * density * outer
        assert (inst.individual[rows] < 4).all() and len(np.unique(inst.individual[rows])) == 4
    # Ids follow the trees' and rows stay sorted by id.
    assert inst.id[~trees].min() >= cfg.scatter.count
    assert (np.diff(inst.id.astype(np.int64)) > 0).all()
    assert set(report.cover) == {"grass", "fern"} and report.cover["grass"][0] == (inst.species == 2).sum()


def test_ground_cover_keeps_trees_and_follows_the_camera_path(tmp_path):
    """Ground cover never moves a tree; a camera path carries it along."""
    plain, _ = scatter(flat(tmp_path, count=2000))
    path = """
[camera]
keys = [ { frame = 1, position = [-40.0, 2.0, -40.0], target = [0.0, 1.0, 0.0] },
         { frame = 24, position = [40.0, 2.0, 40.0], target = [60.0, 1.0, 60.0] } ]
[[ground_cover]]
model = "grass"
density = 1.0
max_distance = 8.0
"""
    cfg = flat(tmp_path, path, count=2000, name="path.toml")
    inst, _ = scatter(cfg)
    trees = inst.subset(inst.species < 2)
    for col in ("id", "position", "tint", "individual"):
        np.testing.assert_array_equal(getattr(trees, col), getattr(plain, col))
    cover = inst.position[inst.species == 2]
    # Along the diagonal from (−40, −40) to (40, 40): within 8 m of it, spread over its whole length.
    off = np.abs(cover[:, 0] - cover[:, 2]) / np.sqrt(2.0)
    assert off.max() <= 8.0 and cover[:, 0].min() < -35 and cover[:, 0].max() > 35


def test_a_scene_with_ground_cover_exports_everywhere(tmp_path):
    """Every exporter takes a scene with ground cover (before, RIB, USD, Blender and points all refused it: "do not
    match the config's [[species]] models", in the check they share), and writes the cover's clumps with the
    trees."""
    from forest.export.points import export_points
    from forest.export.rib import export_rib
    from forest.scene import load_scene

    import ribcheck

    cfg = flat(tmp_path, COVER.replace("density = 4.0", "density = 0.3"), count=100)
    scene = load_scene(cfg)
    inst = scene.instances
    assert (inst.species >= 2).sum() > 20  # clumps of grass and fern
    export_rib(scene, tmp_path / "rib", frames=[1])
    export_points(scene, tmp_path / "points.csv")
    ids = set()
    for path in sorted((tmp_path / "rib").glob("*.rib")):
        ids |= {int(t["name"][5:]) for t in ribcheck.read_trees(ribcheck.parse(path.read_bytes()))}
    assert ids == {int(i) for i in inst.id}  # trees and clumps, every one
    rows = (tmp_path / "points.csv").read_text().strip().splitlines()
    assert len(rows) == 1 + len(inst)


def test_saved_set_with_ground_cover_is_refused_for_another_camera(tmp_path):
    from forest.errors import ConfigError
    from forest.scatter import scene_instances

    cfg = flat(tmp_path, COVER, count=500)
    inst, _ = scatter(cfg)
    path = inst.save(tmp_path / "trees.npz")
    assert len(scene_instances(cfg, path)) == len(inst)
    moved = cfg.with_overrides({"camera.position": [0.0, 1.7, -30.0]})
    with pytest.raises(ConfigError, match="ground_cover: the camera path"):
        scene_instances(moved, path)


def test_scatter_cli_reports_individuals_and_ground_cover(tmp_path):
    cfg = write_scene(
        tmp_path,
        """
        seed = 2
        [terrain]
        flat = { size = 60.0 }
        [scatter]
        count = 300
        [[species]]
        model = "broadleaf"
        percent = 50
        [camera]
        position = [0.0, 1.7, -25.0]
        target = [0.0, 1.0, 0.0]
        [[ground_cover]]
        model = "grass"
        density = 0.5
        max_distance = 10.0
        """,
    )
    r = run_forest("scatter", cfg, "-o", tmp_path / "t.npz")
    assert r.returncode == 0, r.stderr
    assert "individuals: broadleaf 4" in r.stdout
    assert "ground cover: grass" in r.stdout


def test_bad_look_settings_name_the_field(tmp_path):
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 60.0 }
        [[species]]
        model = "broadleaf"
        percent = 50
        colour_jitter = { hue = 3.0, saturation = 0.1 }
        """,
    )
    r = run_forest("scatter", cfg, "-o", tmp_path / "t.npz")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "species[0].colour_jitter.saturation: unknown key" in lines[0]
    assert not (tmp_path / "t.npz").exists()
