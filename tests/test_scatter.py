"""Scatter: area-uniform placement, maps, species rules, spacing, determinism."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import run_forest, write_png, write_scene
from scipy.spatial import cKDTree

from forest.config import load_config
from forest.instances import InstanceSet, quaternion_to_matrix
from forest.scatter import scatter


def _stretched_plane(path, n=24, power=3.0):
    """A flat 100 m × 100 m plane whose grid is squeezed towards x = 0 (very uneven triangles)."""
    s = np.linspace(-1, 1, n)
    xs = np.sign(s) * np.abs(s) ** power * 50.0
    zs = np.linspace(-50, 50, n)
    X, Z = np.meshgrid(xs, zs)
    v = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    trimesh.Trimesh(v, f, process=False).export(path)
    return path


def _ramp_heightmap(path, n=64):
    """Left half flat at 0, right half rising at 45° (height = x for x > 0) on a 100 m terrain."""
    x = np.linspace(-50, 50, n)
    h = np.where(x > 0, x, 0.0) / 50.0
    write_png(path, np.tile(h, (n, 1)), bits=16)
    return path


def test_density_is_uniform_per_area_on_a_stretched_mesh(tmp_path):
    mesh = _stretched_plane(tmp_path / "plane.obj")
    cfg = write_scene(
        tmp_path,
        f"""
        seed = 1
        [terrain]
        mesh = "{mesh.name}"
        [scatter]
        count = 40000
        clumping = {{ strength = 0.0, clearings = 0.0 }}  # even sampling: no stands or clearings
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, _rep = scatter(load_config(cfg))
    assert len(inst) == 40000
    x, z = inst.position[:, 0], inst.position[:, 2]
    counts, _, _ = np.histogram2d(x, z, bins=8, range=[[-50, 50], [-50, 50]])
    expected = 40000 / 64
    # Poisson counts: every equal-area cell within 5 sigma (the original's UV sampling
    # would put ~10x more trees in the squeezed centre columns).
    assert np.abs(counts - expected).max() < 5 * np.sqrt(expected)
    assert counts[3:5].mean() / counts[[0, 7]].mean() == pytest.approx(1.0, abs=0.1)


def test_density_follows_true_surface_area_on_slopes(tmp_path):
    _ramp_heightmap(tmp_path / "ramp.png")
    cfg = write_scene(
        tmp_path,
        """
        seed = 2
        [terrain]
        heightmap = "ramp.png"
        size = [100.0, 100.0]
        height = 50.0
        [scatter]
        count = 40000
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, rep = scatter(load_config(cfg))
    x = inst.position[:, 0]
    left, right = (x < -2).sum(), (x > 2).sum()
    # The 45° half has √2 times the surface area of the flat half.
    assert right / left == pytest.approx(np.sqrt(2), rel=0.05)
    assert rep.area_m2 == pytest.approx(100 * 50 + 100 * 50 * np.sqrt(2), rel=0.01)
    # Trees stand on the surface.
    h = np.where(x > 0, x, 0.0)
    assert np.abs(inst.position[:, 1] - h).max() < 1.0


def test_slope_rule_rejects_steep_ground(tmp_path):
    _ramp_heightmap(tmp_path / "ramp.png")
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        heightmap = "ramp.png"
        size = [100.0, 100.0]
        height = 50.0
        [scatter]
        count = 20000
        [[species]]
        model = "broadleaf"
        percent = 50
        slope_max = 30.0
        [[species]]
        model = "conifer"
        percent = 50
        slope_min = 40.0
    """,
    )
    inst, rep = scatter(load_config(cfg))
    x = inst.position[:, 0]
    broad = inst.species == 0
    # The crease cell can blend normals; away from it the windows are exact.
    assert (x[broad] > 3).sum() == 0
    assert (x[~broad] < -3).sum() == 0
    assert rep.rejected["slope"] > 0.4 * 20000
    assert rep.rejected_by_species["broadleaf"]["slope"] > 0


def test_presence_density_and_altitude_maps(tmp_path):
    n = 32
    pres = np.ones((n, n))
    pres[:, : n // 2] = 0.0  # no trees where x < 0
    dens = np.ones((n, n))
    dens[: n // 2, :] = 0.25  # a quarter of the trees where z < 0
    write_png(tmp_path / "presence.png", pres)
    write_png(tmp_path / "density.png", dens)
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 100.0 }
        [maps]
        presence = "presence.png"
        density = "density.png"
        [scatter]
        count = 40000
        clumping = { strength = 0.0, clearings = 0.0 }  # even sampling: no stands or clearings
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, rep = scatter(load_config(cfg))
    x, z = inst.position[:, 0], inst.position[:, 2]
    assert (x < 0).sum() == 0
    assert rep.rejected["presence"] == pytest.approx(20000, rel=0.03)
    lo, hi = ((x > 0) & (z < 0)).sum(), ((x > 0) & (z > 0)).sum()
    assert lo / hi == pytest.approx(0.25, abs=0.03)


def test_species_percentages_and_empty_ground(flat_scene):
    cfg = flat_scene(
        count=50000,
        species="""
        [[species]]
        model = "broadleaf"
        percent = 50
        [[species]]
        model = "palm"
        percent = 30
        [[species]]
        model = "shrub"
        percent = 10
    """,
    )
    inst, rep = scatter(load_config(cfg))
    frac = np.bincount(inst.species, minlength=3) / 50000
    np.testing.assert_allclose(frac, [0.5, 0.3, 0.1], atol=0.01)
    assert rep.rejected["empty ground"] / 50000 == pytest.approx(0.1, abs=0.01)
    assert inst.species_names == ["broadleaf", "palm", "shrub"]


def test_scale_yaw_and_phase_ranges(flat_scene):
    inst, _ = scatter(
        load_config(
            flat_scene(
                species="""
        [[species]]
        model = "broadleaf"
        percent = 100
        scale = [0.5, 2.0]
    """
            )
        )
    )
    assert inst.scale.min() >= 0.5 and inst.scale.max() <= 2.0
    assert inst.scale.std() > 0.3
    assert inst.yaw.min() >= 0 and inst.yaw.max() < 2 * np.pi and inst.yaw.std() > 1.5
    # Upright trees: the rotation is a pure yaw about +Y.
    R = quaternion_to_matrix(inst.rotation)
    np.testing.assert_allclose(R[:, :, 1], np.tile([0, 1, 0], (len(inst), 1)), atol=1e-5)
    np.testing.assert_allclose(np.arctan2(R[:, 0, 2], R[:, 0, 0]) % (2 * np.pi), inst.yaw, atol=1e-4)


def test_alignment_to_the_terrain_normal(tmp_path):
    _ramp_heightmap(tmp_path / "ramp.png")
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        heightmap = "ramp.png"
        size = [100.0, 100.0]
        height = 50.0
        [scatter]
        count = 2000
        align_to_normal = 1.0
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, _ = scatter(load_config(cfg))
    up = quaternion_to_matrix(inst.rotation)[:, :, 1]
    np.testing.assert_allclose(up, inst.normal, atol=1e-4)
    steep = inst.position[:, 0] > 5
    np.testing.assert_allclose(
        inst.normal[steep], np.tile([-np.sqrt(0.5), np.sqrt(0.5), 0], (steep.sum(), 1)), atol=1e-3
    )


def test_poisson_disk_minimum_distance(tmp_path):
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 100.0 }
        [scatter]
        count = 6000
        min_distance = 2.0
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, rep = scatter(load_config(cfg))
    d, _ = cKDTree(inst.position).query(inst.position, k=2)
    assert d[:, 1].min() >= 2.0
    assert rep.rejected["min_distance"] > 0
    # Maximal (dart throwing): every candidate that was thinned out lies within
    # 2 m of a kept tree.  The same seed without spacing gives all candidates.
    all_c, _ = scatter(
        load_config(write_scene(tmp_path, cfg.read_text().replace("min_distance = 2.0", ""), "all.toml"))
    )
    dropped = all_c.position[~np.isin(all_c.id, inst.id)]
    assert len(dropped) == rep.rejected["min_distance"]
    d2, _ = cKDTree(inst.position).query(dropped)
    assert d2.max() <= 2.0


def test_colour_map_tints_are_linear(tmp_path):
    col = np.zeros((8, 8, 3))
    col[:, :4] = (1.0, 0.5, 0.0)  # sRGB orange where x < 0
    col[:, 4:] = (0.0, 0.0, 1.0)  # blue where x > 0
    write_png(tmp_path / "colour.png", col)
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 80.0 }
        [maps]
        colour = "colour.png"
        colour_normalise = "none"   # the map as painted, no jitter: the decoded values themselves
        [scatter]
        count = 3000
        [[species]]
        model = "broadleaf"
        percent = 100
        colour_jitter = { hue = 0.0, value = 0.0 }
    """,
    )
    inst, _ = scatter(load_config(cfg))
    left = inst.position[:, 0] < -10
    right = inst.position[:, 0] > 10
    # sRGB 0.5 (128/255) decodes to linear 0.2158.
    np.testing.assert_allclose(inst.tint[left], np.tile([1.0, 0.2158605, 0.0], (left.sum(), 1)), atol=2e-3)
    np.testing.assert_allclose(inst.tint[right], np.tile([0.0, 0.0, 1.0], (right.sum(), 1)), atol=1e-5)


def test_partitions_with_tolerance_and_unlabelled_report(tmp_path):
    part = np.zeros((10, 10, 3))
    part[:, :3] = (1.0, 0.02, 0.0)  # near-red: within tolerance of #ff0000
    part[:, 3:7] = (0.0, 1.0, 0.0)
    part[:, 7:] = (0.5, 0.5, 0.5)  # grey: unlabelled
    write_png(tmp_path / "part.png", part)
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 100.0 }
        [maps]
        partition = "part.png"
        [partitions]
        "#ff0000" = "foreground"
        "#00ff00" = "midground"
        "#0000ff" = "background"
        [scatter]
        count = 5000
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, rep = scatter(load_config(cfg))
    assert inst.partition_names == ["foreground", "midground", "background", "unlabelled"]
    x = inst.position[:, 0]
    names = np.array(inst.partition_names)[inst.partition]
    assert (names[x < -22] == "foreground").all()
    assert (names[(x > -18) & (x < 18)] == "midground").all()
    assert (names[x > 22] == "unlabelled").all()
    assert rep.partitions["background"] == 0
    assert rep.unlabelled_pixels == 30
    assert any("#808080" in w for w in rep.warnings)


def test_same_seed_gives_identical_files_and_ids_are_stable(tmp_path, flat_scene):
    cfg = flat_scene(count=3000)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    assert run_forest("scatter", cfg, "-o", a).returncode == 0
    r = run_forest("scatter", cfg, "-o", b)
    assert r.returncode == 0, r.stderr
    assert a.read_bytes() == b.read_bytes()
    assert "3,000 trees" in r.stdout and "broadleaf 3,000" in r.stdout
    c = tmp_path / "c.npz"
    assert run_forest("scatter", cfg, "-o", c, "--seed", "4").returncode == 0
    assert a.read_bytes() != c.read_bytes()
    # Stable ids: removing trees with a presence map keeps the survivors' attributes.
    full = InstanceSet.load(a)
    pres = np.ones((4, 4))
    pres[:, :2] = 0
    write_png(tmp_path / "p.png", pres)
    text = cfg.read_text() + '\n[maps]\npresence = "p.png"\n'
    part_cfg = write_scene(tmp_path, text, "part.toml")
    half, _ = scatter(load_config(part_cfg))
    common, ia, ib = np.intersect1d(full.id, half.id, return_indices=True)
    assert len(common) == len(half)
    np.testing.assert_array_equal(full.position[ia], half.position[ib])
    np.testing.assert_array_equal(full.scale[ia], half.scale[ib])


def test_instance_file_is_plain_numpy(tmp_path, flat_scene):
    out = tmp_path / "t.npz"
    assert run_forest("scatter", flat_scene(count=500), "-o", out, "-q").returncode == 0
    with np.load(out) as z:
        for k in ("id", "position", "rotation", "scale", "species", "tint", "partition"):
            assert k in z.files
        assert z["position"].shape == (500, 3)
        assert list(z["species_names"]) == ["broadleaf"]


def test_procedural_and_16bit_heightmap_terrains(tmp_path):
    cfg = write_scene(
        tmp_path,
        """
        seed = 5
        [terrain]
        procedural = { size = 500.0, height = 80.0, octaves = 5, resolution = 64 }
        [scatter]
        count = 1000
        [[species]]
        model = "broadleaf"
        percent = 100
    """,
    )
    inst, _ = scatter(load_config(cfg))
    assert inst.position[:, 1].min() >= 0.0 and inst.position[:, 1].max() <= 80.0
    assert inst.position[:, 1].std() > 5.0
    h = np.linspace(0, 1, 256)[None, :].repeat(4, 0)
    write_png(tmp_path / "h16.png", h, bits=16)
    from forest.terrain import load_terrain

    t = load_terrain(
        load_config(
            write_scene(
                tmp_path,
                """
        [terrain]
        heightmap = "h16.png"
        size = [255.0, 10.0]
        height = 255.0
        [[species]]
        model = "a"
        percent = 1
    """,
                "h.toml",
            )
        ).terrain
    )
    # 16-bit precision survives: heights step by 1 m exactly per column.
    np.testing.assert_allclose(np.diff(t.vertices[:256, 1]), 1.0, atol=1e-3)
    np.testing.assert_allclose(t.height_at([0.0, 100.0], [0.0, 0.0]), [127.5, 227.5], atol=1e-3)


def test_yaw_step_snaps_rotations(flat_scene):
    inst, _ = scatter(
        load_config(
            flat_scene(
                species="""
        [[species]]
        model = "tower"
        percent = 50
        yaw_step = 90.0
        [[species]]
        model = "broadleaf"
        percent = 50
    """
            )
        )
    )
    blocks = inst.species == 0
    q = np.degrees(inst.yaw[blocks]) / 90.0
    np.testing.assert_allclose(q, np.round(q), atol=1e-4)
    assert len(np.unique(np.round(q) % 4)) == 4
    assert len(np.unique(inst.yaw[~blocks])) == (~blocks).sum()


def test_species_limited_to_partitions(tmp_path):
    part = np.zeros((4, 4, 3))
    part[:, :2] = (1.0, 0.0, 0.0)
    part[:, 2:] = (0.0, 1.0, 0.0)
    write_png(tmp_path / "part.png", part)
    cfg = write_scene(
        tmp_path,
        """
        [terrain]
        flat = { size = 100.0 }
        [maps]
        partition = "part.png"
        [partitions]
        "#ff0000" = "foreground"
        "#00ff00" = "background"
        [scatter]
        count = 4000
        clumping = { strength = 0.0, clearings = 0.0 }  # even sampling: no stands or clearings
        [[species]]
        model = "broadleaf"
        percent = 50
        partitions = ["foreground"]
        [[species]]
        model = "conifer"
        percent = 50
    """,
    )
    inst, rep = scatter(load_config(cfg))
    x = inst.position[:, 0]
    assert (x[inst.species == 0] < 0).all()
    assert (x[inst.species == 1] > 0).any() and (x[inst.species == 1] < 0).any()
    assert rep.rejected["partition"] == pytest.approx(1000, rel=0.15)
    bad = write_scene(tmp_path, cfg.read_text().replace('["foreground"]', '["nowhere"]'), "bad.toml")
    with pytest.raises(Exception, match=r"species\[0\]\.partitions: unknown region 'nowhere'"):
        scatter(load_config(bad))
