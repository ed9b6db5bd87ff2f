"""Points export: one point per tree with the attribute names every DCC instances from.

Houdini, Katana, Maya/MASH, Blender and game engines instance copies onto
points; the de-facto attribute names (Houdini's, which the others read) are:

=========== ======================= =============================================
attribute   type                    meaning
=========== ======================= =============================================
``P``       float × 3               the tree's base, world metres (Y up)
``orient``  float × 4 (x, y, z, w)  its rotation as a unit quaternion, imaginary
                                    part first — the InstanceSet stores (w, x, y, z)
``pscale``  float                   its uniform scale
``id``      int                     the InstanceSet's stable tree id
``species`` int                     index into the species names (the config's
                                    ``[[species]]`` ``model`` strings)
``Cd``      float × 3               the tree's tint (linear RGB): colour map × leaf tint
=========== ======================= =============================================

so a copy or instancer node needs no attribute wrangling: the object→world
matrix is T(P) · R(orient) · S(pscale), the InstanceSet's M = T·R·S.

Formats, by the output's suffix:

* ``.usda`` / ``.usd`` / ``.usdc`` — a ``UsdGeomPoints`` prim ``/Trees`` (Y up,
  metres): ``points`` = P, ``ids`` = id, and ``primvars:orient`` (quatf),
  ``primvars:pscale``, ``primvars:species``, ``primvars:Cd`` with vertex
  interpolation; ``primvars:speciesNames`` (constant string[]) names the
  species.  Solaris imports it as a point cloud with those attributes.
* ``.ply`` — binary little-endian, one ``vertex`` element with the properties
  ``x y z orient_x orient_y orient_z orient_w pscale id species cd_r cd_g cd_b``
  (float32; ``id`` as ``uint``: PLY has no 64-bit integer, so an id above
  2³²−1 is refused), species names in ``comment species <index> <name>`` lines.
* ``.csv`` — a header row ``id,species,species_name,P.x,P.y,P.z,orient.x,…,pscale,Cd.r,Cd.g,Cd.b``
  and one row per tree, floats with 9 significant digits (every float32 reads
  back to the same bits).

Values are the InstanceSet's own float32 numbers, so every format round-trips
them exactly (tests).  Files are written atomically; the same scene gives
byte-identical files.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import ForestError, ParameterError
from ..instances import InstanceSet
from ..scene import Scene
from .common import check_instances, look_instances

SUFFIXES = (".usda", ".usd", ".usdc", ".ply", ".csv")


@dataclass
class PointsExport:
    """What :func:`export_points` wrote."""

    path: Path
    trees: int
    seconds: float


def point_attributes(instances: InstanceSet) -> dict[str, np.ndarray]:
    """The standard attributes of every tree (see the module docstring), float32 / int64 arrays."""
    return {
        "P": np.ascontiguousarray(instances.position, dtype=np.float32),
        "orient": np.ascontiguousarray(instances.rotation[:, [1, 2, 3, 0]], dtype=np.float32),
        "pscale": np.ascontiguousarray(instances.scale, dtype=np.float32),
        "id": instances.id.astype(np.int64),
        "species": instances.species.astype(np.int32),
        "Cd": np.ascontiguousarray(instances.tint, dtype=np.float32),
    }


def _write_usd(path: Path, tmp: Path, attrs: dict, names: list[str]) -> None:
    from pxr import Sdf, Usd, UsdGeom, Vt

    fmt = "usda" if path.suffix.lower() == ".usda" else "usdc"
    tmp.unlink()  # the layer is created afresh at the temporary name
    layer = Sdf.Layer.CreateNew(str(tmp), args={"format": fmt})
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    pts = UsdGeom.Points.Define(stage, "/Trees")
    stage.SetDefaultPrim(pts.GetPrim())
    pts.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(attrs["P"]))
    pts.CreateIdsAttr(Vt.Int64Array.FromNumpy(attrs["id"]))
    if len(attrs["P"]):
        p = attrs["P"]
        pts.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([p.min(axis=0), p.max(axis=0)])))
    api = UsdGeom.PrimvarsAPI(pts)
    T, vertex = Sdf.ValueTypeNames, UsdGeom.Tokens.vertex
    api.CreatePrimvar("orient", T.QuatfArray, vertex).Set(Vt.QuatfArray.FromNumpy(attrs["orient"]))
    api.CreatePrimvar("pscale", T.FloatArray, vertex).Set(Vt.FloatArray.FromNumpy(attrs["pscale"]))
    api.CreatePrimvar("species", T.IntArray, vertex).Set(Vt.IntArray.FromNumpy(attrs["species"]))
    api.CreatePrimvar("Cd", T.Color3fArray, vertex).Set(Vt.Vec3fArray.FromNumpy(attrs["Cd"]))
    api.CreatePrimvar("speciesNames", T.StringArray, UsdGeom.Tokens.constant).Set(list(names))
    layer.Save()
    del stage, layer


PLY_FIELDS = [
    ("x", "<f4"),
    ("y", "<f4"),
    ("z", "<f4"),
    ("orient_x", "<f4"),
    ("orient_y", "<f4"),
    ("orient_z", "<f4"),
    ("orient_w", "<f4"),
    ("pscale", "<f4"),
    ("id", "<u4"),
    ("species", "<i4"),
    ("cd_r", "<f4"),
    ("cd_g", "<f4"),
    ("cd_b", "<f4"),
]
PLY_TYPES = {"<f4": "float", "<u4": "uint", "<i4": "int"}


def _write_ply(tmp: Path, attrs: dict, names: list[str]) -> None:
    n = len(attrs["P"])
    if n and int(attrs["id"].max()) > np.iinfo(np.uint32).max:
        raise ForestError("instances: a tree id exceeds 2^32 - 1, which PLY cannot hold; export .usd or .csv")
    rec = np.empty(n, dtype=np.dtype(PLY_FIELDS))
    for k, c in enumerate("xyz"):
        rec[c] = attrs["P"][:, k]
        rec[f"orient_{c}"] = attrs["orient"][:, k]
        rec[f"cd_{'rgb'[k]}"] = attrs["Cd"][:, k]
    rec["orient_w"] = attrs["orient"][:, 3]
    rec["pscale"] = attrs["pscale"]
    rec["id"] = attrs["id"]
    rec["species"] = attrs["species"]
    head = ["ply", "format binary_little_endian 1.0", "comment forest trees: P orient(x,y,z,w) pscale id species Cd"]
    head += [f"comment species {i} {name}" for i, name in enumerate(names)]
    head += [f"element vertex {n}"] + [f"property {PLY_TYPES[t]} {f}" for f, t in PLY_FIELDS] + ["end_header"]
    with open(tmp, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode())
        fh.write(rec.tobytes())


CSV_COLUMNS = "id,species,species_name,P.x,P.y,P.z,orient.x,orient.y,orient.z,orient.w,pscale,Cd.r,Cd.g,Cd.b"


def _write_csv(tmp: Path, attrs: dict, names: list[str]) -> None:
    """One row per tree; ``%.9g`` prints every float32 so that it reads back to the same bits."""

    def quote(s: str) -> str:
        return '"' + s.replace('"', '""') + '"'

    label = [quote(s) for s in names]
    row = "%d,%d,%s," + ",".join(["%.9g"] * 11)
    floats = np.concatenate([attrs["P"], attrs["orient"], attrs["pscale"][:, None], attrs["Cd"]], axis=1)
    with open(tmp, "w", newline="\n") as fh:
        fh.write(CSV_COLUMNS + "\n")
        step = 65536
        for s in range(0, len(floats), step):
            block = floats[s : s + step].astype(np.float64).tolist()
            ids = attrs["id"][s : s + step].tolist()
            sp = attrs["species"][s : s + step].tolist()
            fh.write("".join(row % (i, k, label[k], *f) + "\n" for i, k, f in zip(ids, sp, block)))


def export_points(scene: Scene, path: str | Path, *, progress=None) -> PointsExport:
    """Write one point per tree of ``scene`` to ``path`` (``.usda``, ``.usd``, ``.usdc``, ``.ply`` or ``.csv``)."""
    t0 = time.perf_counter()
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ParameterError("output", f"{path}: a points file must end in {', '.join(SUFFIXES)}")
    if path.is_dir():
        raise ParameterError("output", f"{path}: is a folder; give the points file's name")
    check_instances(scene.config, scene.instances)
    attrs = point_attributes(look_instances(scene))
    names = [str(n) for n in scene.instances.species_names]
    report = progress or (lambda _f, _m="": None)
    report(0.1, "points")
    try:
        with atomic_path(path) as tmp:
            if suffix in (".usda", ".usd", ".usdc"):
                _write_usd(path, tmp, attrs, names)
            elif suffix == ".ply":
                _write_ply(tmp, attrs, names)
            else:
                _write_csv(tmp, attrs, names)
    except OSError as e:
        raise ForestError(f"{path}: cannot write the points: {e.strerror or e}") from None
    report(1.0, "done")
    return PointsExport(path, len(scene.instances), time.perf_counter() - t0)
