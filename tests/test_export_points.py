"""Points export: every format round-trips positions, orientations, scales, ids, species and tints exactly."""

import csv

import numpy as np
import pytest
import trimesh
from pxr import Usd, UsdGeom

from forest.errors import ParameterError
from forest.export.points import export_points
from forest.scene import load_scene

from export_support import FakeLibrary, make_config, make_instances


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("points")
    inst = make_instances(2500, seed=9)
    return load_scene(make_config(tmp, ""), inst, library=FakeLibrary())


def check(inst, P, orient, pscale, ids, species, Cd):
    """Exact equality with the InstanceSet: orient is (x, y, z, w), the InstanceSet's rotation (w, x, y, z)."""
    np.testing.assert_array_equal(np.asarray(P, np.float32), inst.position)
    np.testing.assert_array_equal(np.asarray(orient, np.float32), inst.rotation[:, [1, 2, 3, 0]])
    np.testing.assert_array_equal(np.asarray(pscale, np.float32), inst.scale)
    np.testing.assert_array_equal(np.asarray(ids).astype(np.uint64), inst.id)
    np.testing.assert_array_equal(np.asarray(species), inst.species)
    np.testing.assert_array_equal(np.asarray(Cd, np.float32), inst.tint)


@pytest.mark.parametrize("suffix", [".usda", ".usd", ".usdc"])
def test_usd_points_round_trip(tmp_path, scene, suffix):
    res = export_points(scene, tmp_path / f"trees{suffix}")
    stage = Usd.Stage.Open(str(res.path))
    pts = UsdGeom.Points(stage.GetDefaultPrim())
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    pv = UsdGeom.PrimvarsAPI(pts)
    orient = np.array([[q.imaginary[0], q.imaginary[1], q.imaginary[2], q.real] for q in pv.GetPrimvar("orient").Get()])
    check(
        scene.instances,
        np.array(pts.GetPointsAttr().Get()),
        orient,
        np.array(pv.GetPrimvar("pscale").Get()),
        np.array(pts.GetIdsAttr().Get()),
        np.array(pv.GetPrimvar("species").Get()),
        np.array(pv.GetPrimvar("Cd").Get()),
    )
    assert list(pv.GetPrimvar("speciesNames").Get()) == scene.instances.species_names
    assert pv.GetPrimvar("orient").GetInterpolation() == UsdGeom.Tokens.vertex


def test_ply_round_trips_through_trimesh(tmp_path, scene):
    res = export_points(scene, tmp_path / "trees.ply")
    cloud = trimesh.load(res.path, process=False)
    v = cloud.metadata["_ply_raw"]["vertex"]["data"]
    check(
        scene.instances,
        np.stack([v["x"], v["y"], v["z"]], 1),
        np.stack([v[f"orient_{c}"] for c in "xyzw"], 1),
        v["pscale"],
        v["id"],
        v["species"],
        np.stack([v[f"cd_{c}"] for c in "rgb"], 1),
    )
    head = res.path.read_bytes().split(b"end_header")[0].decode()
    assert "comment species 0 oak" in head and "comment species 1 pine" in head


def test_csv_round_trips(tmp_path, scene):
    res = export_points(scene, tmp_path / "trees.csv")
    with open(res.path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    col = lambda *names: np.array([[float(r[n]) for n in names] for r in rows])  # noqa: E731
    check(
        scene.instances,
        col("P.x", "P.y", "P.z"),
        col("orient.x", "orient.y", "orient.z", "orient.w"),
        col("pscale")[:, 0],
        np.array([int(r["id"]) for r in rows]),
        np.array([int(r["species"]) for r in rows]),
        col("Cd.r", "Cd.g", "Cd.b"),
    )
    names = scene.instances.species_names
    assert all(r["species_name"] == names[int(r["species"])] for r in rows)


def test_the_matrix_is_t_r_s(tmp_path, scene):
    """A DCC's T(P)·R(orient)·S(pscale) is the InstanceSet's object-to-world matrix."""
    from scipy.spatial.transform import Rotation

    res = export_points(scene, tmp_path / "trees.ply")
    v = trimesh.load(res.path, process=False).metadata["_ply_raw"]["vertex"]["data"]
    R = Rotation.from_quat(np.stack([v[f"orient_{c}"] for c in "xyzw"], 1).astype(np.float64)).as_matrix()
    M = np.zeros((len(v), 4, 4))
    M[:, :3, :3] = R * v["pscale"].astype(np.float64)[:, None, None]
    M[:, :3, 3] = np.stack([v["x"], v["y"], v["z"]], 1)
    M[:, 3, 3] = 1
    np.testing.assert_allclose(M, scene.instances.matrices(), atol=1e-6)


def test_same_scene_same_bytes_and_bad_names(tmp_path, scene):
    for suffix in (".usda", ".ply", ".csv"):
        a = export_points(scene, tmp_path / f"a{suffix}").path.read_bytes()
        assert a == export_points(scene, tmp_path / f"b{suffix}").path.read_bytes()
    with pytest.raises(ParameterError, match=r"must end in \.usda, \.usd, \.usdc, \.ply, \.csv"):
        export_points(scene, tmp_path / "trees.abc")
    assert not (tmp_path / "trees.abc").exists()
