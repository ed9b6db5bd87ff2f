"""RIB export: every file passes the RI 3.2 checker, and the trees read back exactly."""

import math
from pathlib import Path

import numpy as np
import pytest

from forest.camera import camera_at
from forest.errors import ConfigError, ForestError
from forest.export.rib import export_rib
from forest.lights import resolve_lights
from forest.scene import load_scene

import ribcheck
from export_support import FakeLibrary, fly_keys, make_config, make_instances

LOD = "\n[lod]\ndistances = [40.0, 120.0, 300.0]\n"
FLY = fly_keys(last_frame=3)


@pytest.fixture(scope="module")
def lib():
    return FakeLibrary()


@pytest.fixture(scope="module")
def exported(tmp_path_factory, lib):
    """An export with LOD, a fly-through with motion blur and an empty partition."""
    tmp = tmp_path_factory.mktemp("rib")
    cfg = make_config(tmp, LOD + FLY).with_overrides({"camera.shutter": 0.5})
    inst = make_instances(700)
    res = export_rib(load_scene(cfg, inst, library=lib), tmp / "out")
    return cfg, inst, res, tmp / "out"


def test_every_file_passes_the_checker(exported):
    _cfg, _inst, res, out = exported
    calls = ribcheck.check_export(out)
    assert set(calls) == {p.relative_to(out).as_posix() for p in res.files}
    assert all(p.stat().st_size > 0 for p in out.rglob("*") if p.is_file())


def test_no_file_for_an_empty_partition_and_no_strays(exported):
    _cfg, _inst, res, out = exported
    assert sorted(res.instance_files) == ["north", "south"]
    assert not list(out.glob("instances_east*"))
    # the camera's fov changes along the path and LOD is on: each frame has its own raster areas
    want = [f"instances_{p}_{f:04d}.rib" for p in ("north", "south") for f in (1, 2, 3)]
    assert sorted(p.name for p in out.glob("instances_*")) == want
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temp folders left
    scenes = sorted(p.name for p in out.glob("scene_*.rib"))
    assert scenes == ["scene_0001.rib", "scene_0002.rib", "scene_0003.rib"]


def test_trees_read_back_to_float_precision(exported, lib):
    _cfg, inst, res, _out = exported
    M = inst.matrices()
    by_id = {int(i): k for k, i in enumerate(inst.id)}
    seen = []
    for pname, path in res.instance_files.items():
        trees = ribcheck.read_trees(ribcheck.parse(path.read_bytes()))
        p_index = inst.partition_names.index(pname)
        assert len(trees) == int((inst.partition == p_index).sum())
        for t in trees:
            k = by_id[int(t["name"][5:])]
            seen.append(k)
            assert inst.partition[k] == p_index
            scale = max(1.0, float(np.abs(M[k]).max()))
            np.testing.assert_allclose(t["matrix"], M[k], rtol=0, atol=1e-6 * scale)
            np.testing.assert_allclose(t["color"], inst.tint[k], rtol=0, atol=1e-7)
            sp = lib.resolve(inst.species_names[inst.species[k]])
            # a level of detail per band; each archive is this species' level with its measured bound
            names = [Path(a).stem for a, _ in t["archives"]]
            levels = [l.name for l in sp.lods][: len(t["archives"])]
            assert names == [f"{sp.name}_{l}" for l in levels]
            for (_, bound), lvl in zip(t["archives"], sp.lods):
                b = np.asarray(lvl.bounds)
                want = np.array([b[0, 0], b[1, 0], b[0, 1], b[1, 1], b[0, 2], b[1, 2]])
                assert np.all(bound[0::2] <= want[0::2]) and np.all(bound[1::2] >= want[1::2])
                np.testing.assert_allclose(bound, want, atol=1.01e-6)
            assert len(t["ranges"]) == len(t["archives"])
    assert sorted(seen) == list(range(len(inst)))


def test_detail_ranges_switch_levels_at_the_configured_distances(exported):
    """Level k hands over to level k+1 where the detail bound's raster area is A(d_k) = h·w·(f/d_k)²,
    cross-fading between A(d_k (1+τ)) and A(d_k (1−τ))."""
    cfg, _inst, res, _out = exported
    tau = 0.1
    trees = ribcheck.read_trees(ribcheck.parse(res.instance_files["north"].read_bytes()))
    t = next(t for t in trees if len(t["archives"]) == 4)
    d = t["detail"]
    area = (d[3] - d[2]) * max(d[1] - d[0], d[5] - d[4])
    f = (cfg.render.width / 2) / math.tan(math.radians(cfg.camera.fov) / 2)

    def A(dist):
        return area * (f / dist) ** 2

    ranges = np.array(t["ranges"])  # [minvisible, lowertransition, uppertransition, maxvisible]
    for k, dist in enumerate(cfg.lod.distances):
        near, far = ranges[k], ranges[k + 1]
        assert near[0] == pytest.approx(A(dist * (1 + tau)), rel=1e-5)
        assert near[1] == pytest.approx(A(dist * (1 - tau)), rel=1e-5)
        assert (far[2], far[3]) == pytest.approx((near[0], near[1]), rel=1e-9)
        assert near[0] < A(dist) < near[1]
    assert ranges[0][2] >= 1e37 and ranges[-1][0] == ranges[-1][1] == 0


def test_archives_hold_the_library_meshes_inside_their_bounds(exported, lib):
    _cfg, inst, res, out = exported
    objects = ribcheck.objects(ribcheck.check_file(out / "objects.rib", in_world=True))
    for path in res.archives:
        name, level = path.stem.rsplit("_", 1)
        lod = next(l for l in lib.resolve(name).lods if l.name == level)
        handles = [c.args[0] for c in ribcheck.check_file(path, in_world=True) if c.name == "ObjectInstance"]
        meshes = [objects[h] for h in handles]  # one retained object per part, each instanced once
        assert len(meshes) == len(lod.parts) and len(set(handles)) == len(handles)
        b = np.asarray(lod.bounds)
        for m, part in zip(meshes, lod.parts):
            src = part.load()
            # the same triangles, each wound counter-clockwise about its stored normals
            np.testing.assert_array_equal(np.sort(m["faces"], axis=1), np.sort(src.faces, axis=1))
            v, f = m["P"], m["faces"]
            ng = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
            assert (np.einsum("ij,ij->i", ng, m["N"][f].sum(axis=1)) > 0).all()
            np.testing.assert_allclose(m["P"], src.vertices, atol=1e-6)
            np.testing.assert_allclose(m["N"], src.normals, atol=1e-6)
            np.testing.assert_allclose(m["st"], src.uv, atol=1e-6)
            assert np.all(m["P"] >= b[0] - 1e-6) and np.all(m["P"] <= b[1] + 1e-6)
    # archives are written once per species × level, however many trees and partitions use them
    text = "".join(p.read_text() for p in res.frame_instance_files[1])
    for path in res.archives:
        assert text.count(f'"archives/{path.name}"') == int(
            (inst.species == inst.species_names.index(path.stem.rsplit("_", 1)[0])).sum()
        )


def test_camera_is_left_handed_and_blurred(exported):
    cfg, _inst, _res, out = exported
    for frame in (1, 2, 3):
        calls = ribcheck.parse((out / f"scene_{frame:04d}.rib").read_bytes())
        names = [c.name for c in calls]
        assert names.index("Shutter") < names.index("MotionBegin") < names.index("WorldBegin")
        motion = next(c for c in calls if c.name == "MotionBegin")
        k = len(motion.args[0])
        mats = [np.array(c.args[0]).reshape(4, 4).T for c in calls if c.name == "Transform"]
        assert k == len(mats) == max(2, cfg.render.subframes)
        s = cfg.camera.shutter
        for t, W in zip(motion.args[0], mats):
            st = camera_at(cfg.camera, frame - s / 2 + t)
            assert np.linalg.det(W[:3, :3]) == pytest.approx(-1.0)
            target = W @ np.append(st.target, 1.0)
            assert abs(target[0]) < 1e-6 and abs(target[1]) < 1e-6 and target[2] > 0  # straight ahead
            fwd = st.target - st.position
            right = np.cross(fwd, st.up)
            assert (W @ np.append(st.target + right, 1.0))[0] > 0  # right is +x
            assert (W @ np.append(st.target + st.up, 1.0))[1] > 0  # up is +y
        if frame > 1:
            assert not np.allclose(mats[0], mats[-1])
        proj = next(c for c in calls if c.name == "Projection")
        fov = camera_at(cfg.camera, frame).fov
        want = math.degrees(2 * math.atan(math.tan(math.radians(fov) / 2) * cfg.render.height / cfg.render.width))
        assert proj.args[2][0] == pytest.approx(want, rel=1e-7)
        reads = [c.args[0] for c in calls if c.name == "ReadArchive"]
        assert reads == [
            "objects.rib",
            "terrain.rib",
            f"instances_north_{frame:04d}.rib",
            f"instances_south_{frame:04d}.rib",
        ]


def test_sun_direction_convention(tmp_path, lib):
    cfg = make_config(tmp_path, "").with_overrides({"lights.sun.azimuth": 90.0, "lights.sun.elevation": 30.0})
    d = resolve_lights(cfg).sun.direction
    np.testing.assert_allclose(d, [math.cos(math.radians(30)), 0.5, 0.0], atol=1e-12)  # east = +X
    cfg = cfg.with_overrides({"lights.sun.azimuth": 0.0})
    np.testing.assert_allclose(resolve_lights(cfg).sun.direction, [0.0, 0.5, math.cos(math.radians(30))], atol=1e-12)
    res = export_rib(load_scene(cfg, make_instances(20), library=lib), tmp_path / "a")
    calls = ribcheck.parse(res.scenes[0].read_bytes())
    sun = next(c for c in calls if c.name == "LightSource" and c.args[0] == "distantlight")
    params = dict(zip(sun.args[2::2], sun.args[3::2]))
    light_travel = np.array(params["to"]) - np.array(params["from"])
    np.testing.assert_allclose(-light_travel, resolve_lights(cfg).sun.direction, atol=1e-8)


def test_renderman22_output(tmp_path, lib):
    cfg = make_config(tmp_path, LOD)
    inst = make_instances(200)
    export_rib(load_scene(cfg, inst, library=lib), tmp_path / "r22", renderman22=True)
    calls = ribcheck.check_export(tmp_path / "r22")
    assert not (tmp_path / "r22" / "shaders").exists()
    scene = calls["scene_0001.rib"]
    lights = {c.args[0]: c for c in scene if c.name == "Light"}
    assert set(lights) == {"PxrDistantLight", "PxrDomeLight"}
    # the distant light's +Z (its direction of emission) is turned onto the sunlight's direction −d
    i = scene.index(lights["PxrDistantLight"])
    R = np.array(next(c for c in reversed(scene[:i]) if c.name == "ConcatTransform").args[0]).reshape(4, 4).T
    np.testing.assert_allclose(R[:3, 2], -resolve_lights(cfg).sun.direction, atol=1e-8)
    trees = ribcheck.read_trees(calls["instances_north.rib"])
    assert trees and all(len(t["archives"]) >= 2 for t in trees)
    assert not any(c.name == "Procedural" for c in calls["instances_north.rib"])
    arch = calls[next(k for k in calls if k.startswith("archives/oak_high"))]
    prim = [c for c in arch if c.name == "Pattern" and c.args[0] == "PxrPrimvar"]
    assert prim and all(c.args[c.args.index("string varname") + 1] == ["Cs"] for c in prim)
    assert any(c.name == "Bxdf" and "reference color diffuseColor" in c.args for c in arch)


def test_same_input_gives_identical_bytes(tmp_path, lib):
    cfg = make_config(tmp_path, LOD)
    inst = make_instances(300, seed=11)
    a = export_rib(load_scene(cfg, inst, library=lib), tmp_path / "a")
    export_rib(load_scene(cfg, inst, library=lib), tmp_path / "b")
    fa = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    fb = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert fa == fb and len(fa) == len(a.files) + 2  # + the RSL shader source and prepare.sh
    for rel in fa:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def test_large_partitions_stream_in_chunks(tmp_path, lib, monkeypatch):
    import forest.export.rib as rib

    cfg = make_config(tmp_path, "")
    inst = make_instances(1000, seed=5)
    whole = export_rib(load_scene(cfg, inst, library=lib), tmp_path / "whole")
    monkeypatch.setattr(rib, "CHUNK", 7)
    chunked = export_rib(load_scene(cfg, inst, library=lib), tmp_path / "chunked")
    for p in whole.instance_files:
        assert whole.instance_files[p].read_bytes() == chunked.instance_files[p].read_bytes()


def test_failure_leaves_nothing_behind(tmp_path, lib):
    class Broken(FakeLibrary):
        def resolve(self, model, base_dir=None):
            sp = super().resolve(model, base_dir)
            if model == "pine":
                part = sp.lods[0].parts[0]

                class Bad(type(part)):
                    def load(self):
                        raise ForestError(f"{self.path}: corrupt PLY")

                sp.lods[0].parts = (Bad(**{k: getattr(part, k) for k in part.__dataclass_fields__}),)
            return sp

    cfg = make_config(tmp_path, "")
    with pytest.raises(ForestError, match="corrupt PLY"):
        export_rib(load_scene(cfg, make_instances(50), library=Broken()), tmp_path / "out")
    assert not (tmp_path / "out").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["scene.toml"]


def test_bad_input_names_the_field(tmp_path, lib):
    cfg = make_config(tmp_path, "").with_overrides({"species[1].model": "birch"})
    inst = make_instances(20, species=("oak", "birch"))
    with pytest.raises(ConfigError, match=r"scene.toml: species\[1\]\.model: unknown species 'birch'"):
        export_rib(load_scene(cfg, inst, library=lib), tmp_path / "x")
    cfg = make_config(tmp_path, "[export]\nlod_transition = 0.6\n" + LOD)
    with pytest.raises(ConfigError, match=r"export\.lod_transition"):
        export_rib(load_scene(cfg, make_instances(20), library=lib), tmp_path / "x")
    with pytest.raises(ConfigError, match=r"scene.toml: export.colour: unknown key"):
        export_rib(
            load_scene(make_config(tmp_path, "[export]\ncolour = 1\n"), make_instances(20), library=lib), tmp_path / "x"
        )
    assert not (tmp_path / "x").exists()


def test_no_trees_still_gives_a_scene(tmp_path, lib):
    from forest.instances import InstanceSet

    cfg = make_config(tmp_path, "")
    res = export_rib(load_scene(cfg, InstanceSet.empty(["oak", "pine"]), library=lib), tmp_path / "e")
    assert res.instance_files == {} and res.archives == []
    calls = ribcheck.check_export(tmp_path / "e")
    assert [c.args[0] for c in calls["scene_0001.rib"] if c.name == "ReadArchive"] == ["terrain.rib"]


def test_memory_stays_bounded_as_the_forest_grows(tmp_path, lib, monkeypatch):
    """Instance files stream: 4× the trees → 4× the bytes on disk, about the same peak memory."""
    import tracemalloc

    import forest.export.rib as rib

    monkeypatch.setattr(rib, "CHUNK", 2048)
    cfg = make_config(tmp_path, "")
    peaks, sizes = [], []
    for n in (15000, 60000):
        inst = make_instances(n, seed=n)
        export_rib(load_scene(cfg, inst, library=lib), tmp_path / "warm")  # scratch buffers, imports
        tracemalloc.start()
        res = export_rib(load_scene(cfg, inst, library=lib), tmp_path / f"n{n}")
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        sizes.append(sum(p.stat().st_size for p in res.instance_files.values()))
    assert sizes[1] > 3.5 * sizes[0]
    assert peaks[1] - peaks[0] < 0.25 * (sizes[1] - sizes[0])


def test_corrupt_instances_are_refused(tmp_path, lib):
    cfg = make_config(tmp_path, "")
    inst = make_instances(10)
    inst.position[3, 1] = np.nan
    with pytest.raises(ForestError, match="instances: column 'position' holds NaN"):
        export_rib(load_scene(cfg, inst, library=lib), tmp_path / "out")
    inst = make_instances(10, species=("pine", "oak"))
    with pytest.raises(ForestError, match="do not match the config's"):
        export_rib(load_scene(cfg, inst, library=lib), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_lod_switch_can_live_in_one_archive_per_species(tmp_path, lib):
    inst = make_instances(400, seed=21)
    inline = export_rib(load_scene(make_config(tmp_path, LOD), inst, library=lib), tmp_path / "inline")
    cfg = make_config(tmp_path, LOD + '[export]\nrib_lod = "archive"\n', name="archive.toml")
    res = export_rib(load_scene(cfg, inst, library=lib), tmp_path / "arch")
    calls = ribcheck.check_export(tmp_path / "arch")
    assert sorted(k for k in calls if k.endswith("_lod.rib")) == ["archives/oak_lod.rib", "archives/pine_lod.rib"]
    for part, path in res.instance_files.items():
        per_tree = ribcheck.read_trees(calls[path.name])
        inline_calls = ribcheck.parse(inline.instance_files[part].read_bytes())
        inline_trees = {t["name"]: t for t in ribcheck.read_trees(inline_calls)}

        # the per-tree LOD switch is gone: under half the bytes, beside the lines both write alike (bark factors)
        def switch_bytes(p):
            return sum(len(line) for line in p.read_bytes().splitlines(True) if b"barktint" not in line)

        assert switch_bytes(path) < 0.5 * switch_bytes(inline.instance_files[part])
        for t in per_tree:
            ref = inline_trees[t["name"]]
            np.testing.assert_array_equal(t["matrix"], ref["matrix"])
            ((arch, bound),) = t["archives"]
            assert t["detail"] is None and arch.endswith("_lod.rib")
            np.testing.assert_allclose(bound, ref["detail"], atol=1e-9)  # the union of the levels
            # the archive holds exactly the inline switch: Detail, then DetailRange + level per band
            switch = calls[arch]
            assert [c.args[0] for c in switch if c.name == "Detail"] == [list(ref["detail"])]
            ranges = [c.args[0] for c in switch if c.name == "DetailRange"]
            np.testing.assert_allclose(ranges, ref["ranges"], rtol=1e-12)
            levels = [(c.args[1][0], c.args[2]) for c in switch if c.name == "Procedural"]
            assert [a for a, _ in levels] == [a for a, _ in ref["archives"]]


def test_output_in_the_way_is_a_user_error(tmp_path, lib):
    cfg = make_config(tmp_path, "")
    (tmp_path / "taken").write_text("not a folder")
    with pytest.raises(ForestError, match="exists and is not a folder"):
        export_rib(load_scene(cfg, make_instances(10), library=lib), tmp_path / "taken")
    assert (tmp_path / "taken").read_text() == "not a folder"
