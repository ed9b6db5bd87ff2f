"""The InstanceSet: one row per tree, the hub between scatter and every backend.

Columns (numpy arrays, one row per tree, rows sorted by ``id``):

============  ===========  ====================================================
column        dtype/shape  meaning
============  ===========  ====================================================
id            uint64 (N,)  stable identifier (the candidate's index in the
                           seeded stream: unchanged by map or rule edits that
                           keep the tree)
position      f4 (N, 3)    base of the trunk, metres, Y up
rotation      f4 (N, 4)    orientation quaternion (w, x, y, z): yaw about Y,
                           then tilt towards the terrain normal when aligned
yaw           f4 (N,)      yaw in radians, [0, 2π)
scale         f4 (N,)      uniform scale
species       u2 (N,)      index into ``species_names``
tint          f4 (N, 3)    linear RGB factor of tinted parts (1 = untinted)
partition     i2 (N,)      index into ``partition_names``
normal        f4 (N, 3)    terrain normal at the tree
phase         f4 (N,)      wind phase, radians
individual    u1 (N,)      which individual of its species the tree is: k of
                           ``forest.scene.Scene.individuals[species]`` (the
                           library recipe grown with seed + k); 0 in files
                           written before the column existed
============  ===========  ====================================================

``tint`` is the colour map's tint at the tree (normalised to mean 1,
:func:`forest.maps.colour_tint_grid`) with the tree's hue/value jitter applied
(:func:`forest.tint.tree_tints`): the factor every backend multiplies a tinted
part's colour by.  Ground cover (``[[ground_cover]]``) are rows like trees,
whose species come after the ``[[species]]`` ones in ``species_names``
(:func:`forest.scatter.scatter_models`).

Metadata: ``species_names`` (the ``model`` strings of ``[[species]]``),
``partition_names``, ``extent`` (xmin, zmin, xmax, zmax), ``seed``, and in
``meta``: ``source`` (the config file's name), ``method``, ``height_range`` and
``inputs`` — the SHA-256 of every file the set was scattered from, by config
field (:mod:`forest.scatter.provenance`).

Saved as an uncompressed ``.npz`` of those names, written with fixed zip
timestamps so that the same config and seed give a byte-identical file.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path
from .errors import ForestError

COLUMNS = {
    "id": (np.uint64, ()),
    "position": (np.float32, (3,)),
    "rotation": (np.float32, (4,)),
    "yaw": (np.float32, ()),
    "scale": (np.float32, ()),
    "species": (np.uint16, ()),
    "tint": (np.float32, (3,)),
    "partition": (np.int16, ()),
    "normal": (np.float32, (3,)),
    "phase": (np.float32, ()),
    "individual": (np.uint8, ()),
}
#: Columns a saved set may lack (written before they existed), with the value they load as.
OPTIONAL_COLUMNS = {"individual": 0}
_UNSET = np.zeros(0, dtype=np.uint8)
FORMAT_VERSION = 1


@dataclass
class InstanceSet:
    """One row per tree (columns, metadata and file format in the module docstring)."""

    id: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    yaw: np.ndarray
    scale: np.ndarray
    species: np.ndarray
    tint: np.ndarray
    partition: np.ndarray
    normal: np.ndarray
    phase: np.ndarray
    individual: np.ndarray = field(default_factory=lambda: _UNSET.copy())  # not given: individual 0 everywhere
    species_names: list[str] = field(default_factory=list)
    partition_names: list[str] = field(default_factory=lambda: ["default"])
    extent: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    seed: int = 0
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.id)
        for name, (dtype, shape) in COLUMNS.items():
            value = getattr(self, name)
            if name in OPTIONAL_COLUMNS and (value is None or len(value) == 0):
                value = np.full((n, *shape), OPTIONAL_COLUMNS[name], dtype=dtype)
            a = np.ascontiguousarray(value, dtype=dtype)
            if a.shape != (n, *shape):
                raise ValueError(f"InstanceSet column {name} has shape {a.shape}, expected {(n, *shape)}")
            setattr(self, name, a)

    def __len__(self) -> int:
        return len(self.id)

    # -- construction --------------------------------------------------------
    @classmethod
    def empty(cls, species_names=(), partition_names=("default",), **kw) -> InstanceSet:
        """A set of no rows with the given species and partition names (``kw``: other metadata)."""
        cols: dict[str, Any] = {k: np.zeros((0, *s), dtype=d) for k, (d, s) in COLUMNS.items()}
        return cls(**cols, species_names=list(species_names), partition_names=list(partition_names), **kw)

    def subset(self, mask_or_index) -> InstanceSet:
        """Rows selected by a boolean mask or an index array (order kept)."""
        cols = {k: getattr(self, k)[mask_or_index] for k in COLUMNS}
        return InstanceSet(
            **cols,
            species_names=list(self.species_names),
            partition_names=list(self.partition_names),
            extent=self.extent,
            seed=self.seed,
            meta=dict(self.meta),
        )

    # -- derived -------------------------------------------------------------
    def matrices(self) -> np.ndarray:
        """Object-to-world 4×4 matrices ``(N, 4, 4)`` float64: T · R(rotation) · S(scale)."""
        m = np.zeros((len(self), 4, 4), dtype=np.float64)
        m[:, :3, :3] = quaternion_to_matrix(self.rotation.astype(np.float64)) * self.scale[:, None, None]
        m[:, :3, 3] = self.position
        m[:, 3, 3] = 1.0
        return m

    def counts(self) -> dict:
        """Trees per species name and per partition name: ``{"species": {...}, "partitions": {...}}``."""
        sp = np.bincount(self.species, minlength=len(self.species_names))
        pa = np.bincount(self.partition.astype(np.int64), minlength=len(self.partition_names))
        return {
            "species": dict(zip(self.species_names, sp.tolist())),
            "partitions": dict(zip(self.partition_names, pa.tolist())),
        }

    # -- persistence ---------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Write a deterministic ``.npz`` atomically."""
        path = Path(path)
        meta = {
            "format": FORMAT_VERSION,
            "species_names": list(self.species_names),
            "partition_names": list(self.partition_names),
            "extent": [float(x) for x in self.extent],
            "seed": int(self.seed),
            **self.meta,
        }
        arrays = {k: getattr(self, k) for k in COLUMNS}
        arrays["species_names"] = np.array(self.species_names, dtype=np.str_)
        arrays["partition_names"] = np.array(self.partition_names, dtype=np.str_)
        arrays["extent"] = np.array(self.extent, dtype=np.float64)
        arrays["meta"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8)
        with atomic_path(path, suffix=".npz") as tmp:
            write_npz(tmp, arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> InstanceSet:
        """Read a saved set; a :class:`ForestError` naming the file for anything but a valid, finite one.

        Checked on load (a set edited by another tool can hold anything): the
        columns' shapes, finite values in every float column, ``scale > 0``, a
        non-zero rotation quaternion, and species and partition indices inside
        their name lists (see :func:`check_rows`).
        """
        path = Path(path)
        if path.is_dir():
            raise ForestError(f"{path}: is a folder, not an instance file")
        if not path.is_file():
            kind = "not a regular file" if path.exists() else "instance file not found"
            raise ForestError(f"{path}: {kind}")
        try:
            with open(path, "rb") as f:
                if f.read(4) != b"PK\x03\x04":  # an .npz is a zip archive; np.load would try other formats
                    raise ForestError(f"{path}: not a forest instance file (a .npz written by `forest scatter`)")
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(bytes(z["meta"]).decode())
                cols = {k: z[k] for k in COLUMNS if k not in OPTIONAL_COLUMNS or k in z.files}
            species_names = [str(x) for x in meta.pop("species_names")]
            partition_names = [str(x) for x in meta.pop("partition_names")]
            xmin, zmin, xmax, zmax = (float(x) for x in meta.pop("extent"))
            extent = (xmin, zmin, xmax, zmax)
            seed = int(meta.pop("seed"))
            meta.pop("format", None)
            inst = cls(
                **cols,
                species_names=species_names,
                partition_names=partition_names,
                extent=extent,
                seed=seed,
                meta=meta,
            )
        except (KeyError, ValueError, TypeError, AttributeError, OSError, zipfile.BadZipFile) as e:
            reason = str(e).splitlines()[0] if str(e) else type(e).__name__
            raise ForestError(f"{path}: not a forest instance file ({reason})") from None
        problem = check_rows(inst)
        if problem:
            raise ForestError(f"{path}: {problem}")
        return inst


def check_rows(inst: InstanceSet) -> str | None:
    """What is wrong with a set's values, as a phrase naming the column and the first bad tree; None if nothing.

    Float columns must be finite, ``scale`` positive, ``rotation`` a non-zero
    quaternion, ``species``/``partition`` indices inside their name lists and
    ``extent`` finite.
    """

    def first(bad: np.ndarray) -> str:
        rows = np.flatnonzero(bad)
        return f"{len(rows):,} {'row' if len(rows) == 1 else 'rows'}, the first tree id {int(inst.id[rows[0]])}"

    for name, (dtype, _shape) in COLUMNS.items():
        a = getattr(inst, name)
        if np.issubdtype(dtype, np.floating) and a.size and not np.isfinite(a).all():
            bad = ~np.isfinite(a).reshape(len(a), -1).all(axis=1)
            return f"column {name!r} has NaN or infinite values ({first(bad)})"
    if len(inst) and (inst.scale <= 0).any():
        return f"column 'scale' must be > 0 ({first(inst.scale <= 0)})"
    if len(inst):
        zero = np.linalg.norm(inst.rotation, axis=1) < 1e-6
        if zero.any():
            return f"column 'rotation' has zero quaternions ({first(zero)})"
        bad = inst.species >= len(inst.species_names)
        if bad.any():
            return f"column 'species' indexes past its {len(inst.species_names)} species names ({first(bad)})"
        bad = (inst.partition < 0) | (inst.partition >= len(inst.partition_names))
        if bad.any():
            return f"column 'partition' indexes past its {len(inst.partition_names)} partition names ({first(bad)})"
    if not all(np.isfinite(inst.extent)):
        return f"extent {list(inst.extent)} is not finite"
    return None


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes, hex (what an InstanceSet records of the inputs it was scattered from)."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Like :func:`numpy.savez` but byte-deterministic (fixed zip timestamps, sorted names)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = 0o644 << 16
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(arrays[name]), allow_pickle=False)
            zf.writestr(info, buf.getvalue())


def yaw_tilt_quaternion(yaw: np.ndarray, normal: np.ndarray, align: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z): rotate by ``yaw`` about +Y, then tilt +Y towards ``normal``.

    ``align`` in [0, 1] blends the tilt: 0 keeps trees upright, 1 stands them
    along the terrain normal.  q = q_tilt · q_yaw.
    """
    yaw = np.asarray(yaw, dtype=np.float64)
    half = 0.5 * yaw
    qy = np.zeros((len(yaw), 4))
    qy[:, 0] = np.cos(half)
    qy[:, 2] = np.sin(half)
    align = np.asarray(align, dtype=np.float64)
    tilted = np.flatnonzero(align > 0)
    if len(tilted) == 0:
        return qy.astype(np.float32)
    if len(tilted) < len(yaw):
        out = qy.astype(np.float32)
        out[tilted] = yaw_tilt_quaternion(yaw[tilted], np.asarray(normal)[tilted], align[tilted])
        return out
    n = np.asarray(normal, dtype=np.float64)
    up = np.array([0.0, 1.0, 0.0])
    target = up + (n - up) * np.asarray(align, dtype=np.float64)[:, None]
    target /= np.maximum(np.linalg.norm(target, axis=1, keepdims=True), 1e-12)
    axis = np.cross(up, target)  # (-tz ... ) rotation axis, |axis| = sin(angle)
    s = np.linalg.norm(axis, axis=1)
    c = np.clip(target[:, 1], -1.0, 1.0)
    angle = np.arctan2(s, c)
    axis = np.where(s[:, None] > 1e-12, axis / np.maximum(s, 1e-12)[:, None], np.array([1.0, 0.0, 0.0]))
    qt = np.concatenate([np.cos(angle / 2)[:, None], axis * np.sin(angle / 2)[:, None]], axis=1)
    return quaternion_multiply(qt, qy).astype(np.float32)


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, row-wise."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=1,
    )


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (w, x, y, z) → (N, 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
        ],
        axis=1,
    )
