"""forest's own geometry buffers, the Mitsuba traversal scene, and hits rebuilt from preliminary intersections.

Mitsuba 3.9.1 traces instanced scenes in the JIT variants in time linear in the
number of instances (``Scene.ray_intersect_preliminary``, ``ray_test``), but
computing a surface interaction on an instanced hit is a nested virtual call
through every instance's shapegroup, quadratic in their number.  So the
traversal scene here carries only positions and faces, and every hit is
rebuilt from forest's buffers:

* **Parts.** Every mesh that can be hit — each part of each (species,
  individual, level of detail) *prototype*, the terrain, other surfaces — is
  one *part*: a slice of one concatenated vertex buffer (object-space
  positions, normals, uv) and face buffer, and a material index.
* **Rows.** Tree i of the InstanceSet is row i, with its object→world matrix
  M_i (3×4) and normal matrix (M_i⁻¹)ᵀ (3×3); row N (after the trees) is
  the identity, for world-space parts.
* **Traversal scene.** Each instanced prototype is a ``shapegroup`` of its
  parts (positions and faces only, part k named ``part_kk`` — Mitsuba keeps
  their order, which ``pi.shape_index`` reports) and each of its trees an
  ``instance``.  Prototypes with at most ``PathInputs.flatten_triangles``
  (default :data:`FLATTEN_MAX_TRIANGLES`)
  triangles (the far level: crossed cards) are *flattened*: per prototype
  part, one world-space mesh holding the part once per tree, so the instance
  count — about 13–17 KB each in llvm — stays bounded however many far trees
  there are.  The terrain and other surfaces are plain meshes.
* **Resolving a hit.** ``pi.instance`` reinterpreted as UInt32 is the
  instance's registry id (0 for top-level shapes, whose registry id is
  ``pi.shape``).  Tables indexed by registry id give the row (instances), or
  the part and, for flattened meshes, the group whose tree is
  ``rows[⌊prim / triangles(part)⌋]``.  Part p of an instanced tree is
  ``first_part(row) + k``, k the part's index inside its shapegroup: Embree
  (``llvm_ad_rgb``) reports k as ``pi.shape_index`` and a null ``pi.shape``;
  OptiX (``cuda_ad_rgb``) reports the part mesh's registry id as ``pi.shape``
  (mapped to k by a table) and 0 as ``pi.shape_index``.  Then triangle t = face_offset(p) +
  local prim, and with barycentrics (b₁, b₂) = ``pi.prim_uv``:

      x = M (b₀ v₀ + b₁ v₁ + b₂ v₂),  n_g ∝ (x₁ − x₀) × (x₂ − x₀),
      n_s ∝ (M⁻¹)ᵀ (b₀ n₀ + b₁ n₁ + b₂ n₂),  uv = b₀ uv₀ + b₁ uv₁ + b₂ uv₂.

Mitsuba's instance transforms cannot be updated in place at a useful cost
(``mi.traverse`` + ``update`` on 100 instances took 3.1 s, on 300 16.1 s:
quadratic), so a new pose (wind, motion-blur sub-frame) or level-of-detail
plan reloads the traversal scene; the part buffers are kept.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...errors import ForestError
from ...library.mesh import read_ply
from ...memory import available_bytes as available_bytes  # MemAvailable and this process's cgroup limits
from ...progress import ProgressFn, scaled
from ...runtime import load_scene_dict
from .arrays import mappable, owned
from .inputs import Material, PathInputs
from .materials import MaterialStore
from .solid import can_draw_solid, solid_part

#: Trees transformed per block when flattening (bounds the float64 temporaries).
FLATTEN_BLOCK = 131_072
#: Trees between two progress reports while a traversal scene's instances are written.
REPORT_TREES = 10_000
#: Resident memory of one Mitsuba instance in llvm_ad_rgb (``bench/bench_forest_path.py``: 15.7 KB).
INSTANCE_BYTES = 16 * 1024
#: Resident memory per merged triangle: world-space vertices and faces in Mitsuba plus Embree's BVH.
FLAT_TRIANGLE_BYTES = 128


def memory_plan(geometry: ForestGeometry, levels: np.ndarray, solid: np.ndarray | None = None) -> tuple[int, int, int]:
    """(instances, merged triangles, estimated bytes) of the traversal scene for a level-of-detail plan."""
    proto_of_tree, protos = geometry.tree_prototypes(levels, solid=solid)
    counts = np.bincount(proto_of_tree, minlength=len(protos)) if len(proto_of_tree) else np.zeros(len(protos), int)
    instances = int(sum(int(c) for c, p in zip(counts, protos) if not p.flatten))
    flat = int(sum(int(c) * p.triangles for c, p in zip(counts, protos) if p.flatten))
    return instances, flat, instances * INSTANCE_BYTES + flat * FLAT_TRIANGLE_BYTES


@dataclass
class PartBuffers:
    """All parts concatenated: object-space vertices, faces with global vertex indices, per-part slices."""

    vertices: list[np.ndarray] = field(default_factory=list)
    normals: list[np.ndarray] = field(default_factory=list)
    uv: list[np.ndarray] = field(default_factory=list)
    faces: list[np.ndarray] = field(default_factory=list)
    face_offset: list[int] = field(default_factory=list)
    triangles: list[int] = field(default_factory=list)
    material: list[int] = field(default_factory=list)
    local_faces: list[np.ndarray] = field(default_factory=list)  # faces of each part, local vertex indices
    n_vertices: int = 0
    n_faces: int = 0

    def add(self, mesh: Any, material: int) -> int:
        """Append a mesh (``MeshData``-like) as a new part; its index."""
        v = np.ascontiguousarray(mesh.vertices, dtype=np.float32).reshape(-1, 3)
        f = np.ascontiguousarray(mesh.faces, dtype=np.uint32).reshape(-1, 3)
        n = getattr(mesh, "normals", None)
        uv = getattr(mesh, "uv", None)
        if n is None or np.shape(n) != v.shape:
            n = np.zeros_like(v)  # zero normals: the geometric normal is used
        if uv is None or np.shape(uv) != (len(v), 2):
            uv = np.zeros((len(v), 2), np.float32)
        if len(f) and int(f.max()) >= len(v):
            raise ForestError("mesh has a face that references a missing vertex")
        self.vertices.append(v)
        self.normals.append(np.ascontiguousarray(n, dtype=np.float32))
        self.uv.append(np.ascontiguousarray(uv, dtype=np.float32))
        self.faces.append(f + np.uint32(self.n_vertices))
        self.local_faces.append(f)
        self.face_offset.append(self.n_faces)
        self.triangles.append(len(f))
        self.material.append(material)
        self.n_vertices += len(v)
        self.n_faces += len(f)
        return len(self.triangles) - 1


@dataclass
class Prototype:
    """One (species, individual, level of detail, solid cards): its parts and whether its trees are flattened."""

    key: tuple[int, int, int, int]  # species, individual, level, solid cards (0/1)
    parts: tuple[int, ...]
    triangles: int
    flatten: bool


def _species_list(entry: Any) -> list[Any]:
    return list(entry) if isinstance(entry, (list, tuple)) else [entry]


class ForestGeometry:
    """Part buffers and prototypes for the trees of a :class:`PathInputs` (built once, reused per frame)."""

    def __init__(self, inputs: PathInputs, materials: MaterialStore):
        self.parts = PartBuffers()
        self.materials = materials
        self.flatten_triangles = int(inputs.flatten_triangles)
        self.solid = None if inputs.solid is None else np.asarray(inputs.solid, bool)
        self.prototypes: dict[tuple[int, int, int, int], Prototype] = {}
        self._species = [_species_list(e) for e in inputs.species]
        inst = inputs.instances
        self.n_trees = len(inst)
        self.species_index = np.asarray(inst.species, dtype=np.int64)
        self.individual = (
            np.zeros(self.n_trees, np.int64)
            if inputs.individuals is None
            else np.asarray(inputs.individuals, dtype=np.int64)
        )
        for s, lst in enumerate(self._species):
            if not lst:
                raise ForestError(f"path inputs: species {s} has no individuals")
        # World-space parts: the terrain, then other surfaces (row N, the identity).
        self.world_parts: list[int] = []
        if inputs.terrain is not None:
            t = inputs.terrain
            detail = inputs.terrain_detail
            if detail is not None:
                from .ground import detail_rgb

                detail = detail_rgb(detail)
            mat = materials.add(
                Material(
                    "surface",
                    (1.0, 1.0, 1.0) if np.ndim(inputs.terrain_colour) == 3 else inputs.terrain_colour,
                    detail,
                    bool(inputs.terrain_tinted and inputs.colour_grid is not None),
                ),
                terrain_map=np.ndim(inputs.terrain_colour) == 3,
                tint_row=len(inputs.species),  # the ground tint follows the species' leaf tints
            )
            tile = float(inputs.terrain_detail_tile)

            def world_uv(v: np.ndarray) -> np.ndarray | None:
                # The detail repeats every ``tile`` metres of world X/Z (the terrain is world-space).
                return None if detail is None else (np.asarray(v, np.float64)[:, [0, 2]] / tile).astype(np.float32)

            mesh = _Mesh(t.vertices, t.faces, t.vertex_normals, world_uv(t.vertices))
            self.world_parts.append(self.parts.add(mesh, mat))
            if float(inputs.skirt_radius) > 0.0:
                from ...skirt import relief_step, skirt_mesh

                step = relief_step(inputs.camera.fov, inputs.camera.width)
                sk = skirt_mesh(t, float(inputs.skirt_radius), inputs.skirt_hills, inputs.far_cover, step)
                if sk is not None:
                    mesh = _Mesh(sk.vertices, sk.faces, sk.normals, world_uv(sk.vertices))
                    self.world_parts.append(self.parts.add(mesh, mat))
        for srf in inputs.surfaces:
            self.world_parts.append(self.parts.add(srf.mesh, materials.add(srf.material)))
        # Every species' materials — each individual, each level — in one fixed order before any prototype: the
        # texture atlas (packed in the order textures arrive) is then the scene's, not the first frame's, so a
        # frame's pixels do not depend on which frames the process built before it.
        for s, lst in enumerate(self._species):
            for sp in lst:
                for lod in getattr(sp, "lods", ()):
                    for part in lod.parts:
                        materials.add(part, tint_row=s if getattr(part, "tinted", False) else -1)

    def prototype(self, s: int, k: int, level: int, solid: bool = False) -> Prototype:
        """The prototype of species ``s``, individual ``k``, level ``level`` (clamped to its last LOD), its
        cut-out leaf cards drawn solid (:mod:`.solid`) when ``solid``."""
        key = (s, k, level, int(solid))
        if key in self.prototypes:
            return self.prototypes[key]
        lst = self._species[s]
        sp = lst[k % len(lst)]
        lods = sp.lods
        if not lods:
            raise ForestError(f"species {getattr(sp, 'name', s)!r} has no levels of detail")
        lod = lods[min(level, len(lods) - 1)]
        if solid and not any(can_draw_solid(part) for part in lod.parts):
            proto = self.prototype(s, k, level, False)  # nothing to draw solid: the cut-out prototype is the same
            self.prototypes[key] = proto
            return proto
        ids = []
        for part in lod.parts:
            mesh = part.load() if hasattr(part, "load") else read_ply(part.path)
            if len(mesh.faces) == 0:
                continue
            # The leaf tint multiplies the parts the colour map tints (a species' foliage), as every exporter does.
            row = s if getattr(part, "tinted", False) else -1
            if solid:
                mesh, part = solid_part(mesh, part)
            ids.append(self.parts.add(mesh, self.materials.add(part, tint_row=row)))
        if not ids:
            raise ForestError(f"species {getattr(sp, 'name', s)!r} level {lod.name} has no triangles")
        tris = int(sum(self.parts.triangles[i] for i in ids))
        proto = Prototype(key, tuple(ids), tris, tris <= self.flatten_triangles)
        self.prototypes[key] = proto
        return proto

    def tree_prototypes(
        self, levels: np.ndarray, progress: ProgressFn | None = None, *, solid: np.ndarray | None = None
    ) -> tuple[np.ndarray, list[Prototype]]:
        """Per tree the index into the returned list of prototypes (created on first use); ``solid`` (N,) bool:
        the trees whose cut-out leaf cards are drawn solid (None: the inputs' ``solid``).

        ``progress(fraction, message)`` after each prototype (``geometry: 2/6 prototypes (species 2/3, level 0)``):
        reading a species' meshes is the slow part of a first build."""
        levels = np.asarray(levels, dtype=np.int64)
        solid = self.solid if solid is None else np.asarray(solid, bool)
        flag = np.zeros(self.n_trees, np.int64) if solid is None else solid.astype(np.int64)
        cols = [np.asarray(c, np.int64) for c in (self.species_index, self.individual, levels, flag)]
        if self.n_trees:
            # One integer per (species, individual, level, solid), in the rows' lexicographic order: np.unique of
            # a 1-D key takes milliseconds where np.unique(axis=0) of the rows took 0.6 s at 100 000 trees.
            dims = tuple(int(c.max()) + 1 for c in cols)
            codes, inverse = np.unique(np.ravel_multi_index(cols, dims), return_inverse=True)
            uniq = np.stack(np.unravel_index(codes, dims), axis=1)
        else:
            uniq, inverse = np.zeros((0, 4), np.int64), np.zeros(0, np.int64)
        protos = []
        n, species = len(uniq), len(self._species)
        for i, (a, b, c, d) in enumerate(uniq.tolist()):
            protos.append(self.prototype(int(a), int(b), int(c), bool(d)))
            if progress is not None:
                progress(
                    (i + 1) / n, f"geometry: {i + 1}/{n} prototypes (species {int(a) + 1}/{species}, level {int(c)})"
                )
        return np.asarray(inverse, dtype=np.int64).ravel(), protos


@dataclass
class _Mesh:
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None


def _mi_mesh(mi: Any, name: str, vertices: np.ndarray, faces: np.ndarray) -> Any:
    """A Mitsuba mesh with positions and faces only (what traversal needs)."""
    m = mi.Mesh(
        name, vertex_count=len(vertices), face_count=len(faces), has_vertex_normals=False, has_vertex_texcoords=False
    )
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(mappable(np.asarray(vertices, dtype=np.float32).ravel()))
    p["faces"] = mi.UInt32(mappable(np.asarray(faces, dtype=np.uint32).ravel()))
    p.update()
    return m


def registry_ids(mi: Any, shapes: list[Any]) -> np.ndarray:
    """The registry ids of Mitsuba shapes in a JIT variant (what ``pi.shape`` / ``pi.instance`` report), read at once."""
    import drjit as dr

    if not shapes:
        return np.zeros(0, np.int64)
    return np.asarray(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shapes)), np.int64)


def normal_matrices(m: np.ndarray) -> np.ndarray:
    """(N, 3, 3) inverse transposes of the upper 3×3 blocks (singular blocks give zeros)."""
    a = np.asarray(m, dtype=np.float64)[:, :3, :3]
    det = np.linalg.det(a)
    ok = np.abs(det) > 1e-30
    out = np.zeros_like(a)
    if ok.any():
        out[ok] = np.transpose(np.linalg.inv(a[ok]), (0, 2, 1))
    return out


@dataclass
class FrameStats:
    """What one traversal scene holds."""

    trees: int = 0
    instances: int = 0
    flattened_trees: int = 0
    flattened_triangles: int = 0
    shapegroups: int = 0
    instanced_triangles: int = 0
    world_triangles: int = 0  # the terrain, its skirt to the horizon and the surfaces
    load_seconds: float = 0.0
    lod_counts: dict[str, int] = field(default_factory=dict)


class TraversalScene:
    """The Mitsuba scene of one pose (levels + matrices) and the tables that map its hits to forest's buffers.

    ``progress(fraction, message)`` follows the build: the prototypes' meshes (to 0.2), the trees written as
    instances or merged meshes (to 0.6, every :data:`REPORT_TREES` trees), then Mitsuba's ``load_dict`` — one
    call, reported before and after (0.6 and 0.95) — and the hit tables."""

    def __init__(
        self,
        mi: Any,
        geometry: ForestGeometry,
        levels: np.ndarray,
        matrices: np.ndarray,
        progress: ProgressFn | None = None,
        solid: np.ndarray | None = None,
    ):
        import drjit as dr

        report = scaled(progress, 0.0, 1.0)
        t0 = time.perf_counter()
        n = geometry.n_trees
        mats = np.ascontiguousarray(matrices, dtype=np.float64).reshape(n, 4, 4)
        proto_of_tree, protos = geometry.tree_prototypes(
            levels, None if progress is None else scaled(progress, 0, 0.2), solid=solid
        )
        placed = 0  # trees written so far
        parts = geometry.parts
        stats = FrameStats(trees=n)
        counts = np.bincount(np.asarray(levels, np.int64), minlength=4) if n else np.zeros(4, np.int64)
        stats.lod_counts = {
            ("high", "medium", "low", "far")[i] if i < 4 else str(i): int(c) for i, c in enumerate(counts) if c
        }
        entries: dict[str, Any] = {"type": "scene"}
        first_part = np.zeros(n + 1, np.uint32)
        flat_rows: list[np.ndarray] = []
        flat_meta: dict[str, tuple[int, int]] = {}  # mesh id -> (part, offset into flat_rows)
        flat_offset = 0
        top_parts: dict[str, int] = {}
        members: list[tuple[Any, int, int]] = []  # each shapegroup's meshes: (mesh, index in its group, part)
        T, M4 = mi.ScalarTransform4f, mi.ScalarMatrix4f
        for pi_, proto in enumerate(protos):
            rows = np.nonzero(proto_of_tree == pi_)[0]
            if len(rows) == 0:
                continue
            first_part[rows] = proto.parts[0]
            if proto.flatten:
                stats.flattened_trees += len(rows)
                for p in proto.parts:
                    name = f"flat_{pi_}_{p}"
                    v = parts.vertices[p].astype(np.float64)
                    f = parts.local_faces[p]
                    world = np.empty((len(rows), len(v), 3), np.float32)
                    for b in range(0, len(rows), FLATTEN_BLOCK):
                        m = mats[rows[b : b + FLATTEN_BLOCK]]
                        world[b : b + FLATTEN_BLOCK] = np.einsum("nij,vj->nvi", m[:, :3, :3], v) + m[:, None, :3, 3]
                    faces = f[None, :, :].astype(np.int64) + (np.arange(len(rows)) * len(v))[:, None, None]
                    entries[name] = _mi_mesh(mi, name, world.reshape(-1, 3), faces.reshape(-1, 3))
                    stats.flattened_triangles += len(rows) * len(f)
                    flat_meta[name] = (p, flat_offset)
                    flat_rows.append(rows.astype(np.uint32))
                    flat_offset += len(rows)
                placed += len(rows)
                report(min(0.6, 0.2 + 0.4 * placed / n), f"instances {placed:,}/{n:,} (merged far trees)")
                continue
            sg = f"sg_{pi_}"
            group: dict[str, Any] = {"type": "shapegroup"}
            for k, p in enumerate(proto.parts):
                mesh = _mi_mesh(mi, f"{sg}_{k:02d}", parts.vertices[p], parts.local_faces[p])
                group[f"part_{k:02d}"] = mesh
                members.append((mesh, k, p))
            entries[sg] = group
            stats.shapegroups += 1
            ref = {"type": "ref", "id": sg}
            for b in range(0, len(rows), REPORT_TREES):
                block = rows[b : b + REPORT_TREES]
                # Nested lists convert to Mitsuba's matrix in half the time of numpy views (1.3 µs against 2.9).
                for r, m in zip(block.tolist(), mats[block].tolist()):
                    entries[f"tree_{r}"] = {"type": "instance", "shapegroup": ref, "to_world": T(M4(m))}
                placed += len(block)
                report(min(0.6, 0.2 + 0.4 * placed / n), f"instances {placed:,}/{n:,}")
            stats.instances += len(rows)
            stats.instanced_triangles += len(rows) * proto.triangles
        for k, p in enumerate(geometry.world_parts):
            name = f"world_{k}"
            entries[name] = _mi_mesh(mi, name, parts.vertices[p], parts.local_faces[p])
            top_parts[name] = p
            stats.world_triangles += len(parts.local_faces[p])
        if len(entries) == 1:
            raise ForestError("path inputs: nothing to render (no trees, terrain or surfaces)")
        report(0.6, f"Mitsuba scene: loading {len(entries) - 1:,} shapes and instances")
        t_load = time.perf_counter()
        try:
            self.scene = load_scene_dict(mi, entries)
        except Exception as e:
            raise ForestError(f"cannot build the Mitsuba scene: {str(e).splitlines()[0]}") from None
        del entries
        report(0.95, f"Mitsuba scene loaded in {time.perf_counter() - t_load:.1f} s; hit tables")
        # Registry-id tables.
        shapes = self.scene.shapes()
        reg = np.asarray(dr.reinterpret_array(mi.UInt32, self.scene.shapes_dr()), dtype=np.int64)
        member_reg = registry_ids(mi, [m for m, _, _ in members])
        size = max(int(reg.max()) if len(reg) else 0, int(member_reg.max()) if len(member_reg) else 0) + 1
        reg_row = np.full(size, n, np.uint32)
        reg_part = np.zeros(size, np.uint32)
        reg_flat = np.full(size, -1, np.int32)
        reg_local = np.zeros(size, np.uint32)
        reg_local[member_reg] = [k for _, k, _ in members]
        for s, r in zip(shapes, reg.tolist()):
            sid = s.id()
            if sid.startswith("tree_"):
                reg_row[r] = int(sid[5:])
            elif sid in flat_meta:
                p, off = flat_meta[sid]
                reg_part[r], reg_flat[r] = p, off
            elif sid in top_parts:
                reg_part[r] = top_parts[sid]
        rows_all = np.concatenate(flat_rows) if flat_rows else np.zeros(1, np.uint32)
        mat3 = np.zeros((n + 1, 3, 4), np.float32)
        mat3[:n] = mats[:, :3, :]
        mat3[n, :, :3] = np.eye(3)
        nrm = np.zeros((n + 1, 3, 3), np.float32)
        nrm[:n] = normal_matrices(mats) if n else nrm[:n]
        nrm[n] = np.eye(3)
        self.reg_row = owned(mi.UInt32, reg_row)
        self.reg_part = owned(mi.UInt32, reg_part)
        self.reg_flat = owned(mi.Int32, reg_flat)
        self.reg_local = owned(mi.UInt32, reg_local)
        #: part -> registry id of its mesh in a shapegroup (what OptiX reports as ``pi.shape``)
        self.part_mesh_reg = {p: int(r) for (_, _, p), r in zip(members, member_reg)}
        self.flat_rows = owned(mi.UInt32, rows_all)
        #: each merged mesh's first entry in ``flat_rows`` (its trees, in the order their copies were written)
        self.flat_offsets = {name: off for name, (_, off) in flat_meta.items()}
        self.first_part = owned(mi.UInt32, first_part)
        self.row_matrix = owned(mi.Float, mat3.ravel())
        self.row_normal = owned(mi.Float, nrm.ravel())
        self.n_trees = n
        stats.load_seconds = time.perf_counter() - t0
        self.stats = stats


class PartArrays:
    """The part buffers as drjit arrays (built once per scene; grown when new prototypes appear)."""

    def __init__(self, mi: Any, parts: PartBuffers):
        self.count = len(parts.triangles)
        self.vertices = owned(mi.Float, np.concatenate(parts.vertices).ravel()) if parts.vertices else mi.Float(0)
        self.normals = owned(mi.Float, np.concatenate(parts.normals).ravel()) if parts.normals else mi.Float(0)
        self.uv = owned(mi.Float, np.concatenate(parts.uv).ravel()) if parts.uv else mi.Float(0)
        self.faces = owned(mi.UInt32, np.concatenate(parts.faces).ravel()) if parts.faces else mi.UInt32(0)
        self.face_offset = owned(mi.UInt32, np.asarray(parts.face_offset, np.uint32))
        self.triangles = owned(mi.UInt32, np.maximum(np.asarray(parts.triangles, np.uint32), 1))
        self.material = owned(mi.UInt32, np.asarray(parts.material, np.uint32))


@dataclass
class Hit:
    """A resolved intersection: which row, part and triangle, where on it, how far along the ray."""

    valid: Any  # Bool
    t: Any  # Float
    row: Any  # UInt32: tree row, or the identity row N for world-space parts
    tri: Any  # UInt32: global triangle index
    part: Any  # UInt32
    b1: Any  # Float: barycentrics of vertices 1 and 2
    b2: Any


def resolve(mi: Any, scene: TraversalScene, parts: PartArrays, pi: Any, active: Any) -> Hit:
    """Row, part and triangle of a preliminary intersection (see the module docstring)."""
    import drjit as dr

    valid = active & pi.is_valid()
    inst = dr.reinterpret_array(mi.UInt32, pi.instance)
    shape: Any = dr.reinterpret_array(mi.UInt32, pi.shape)
    is_inst = valid & (inst != 0)
    top = valid & ~is_inst
    reg: Any = dr.select(is_inst, inst, shape)
    row = dr.gather(mi.UInt32, scene.reg_row, reg, valid)
    part_top = dr.gather(mi.UInt32, scene.reg_part, reg, top)
    flat = dr.gather(mi.Int32, scene.reg_flat, reg, top)
    # The part's index inside its shapegroup: Embree (llvm) reports it as ``pi.shape_index`` and leaves ``pi.shape``
    # null on instanced hits; OptiX (cuda) reports the part mesh's registry id as ``pi.shape`` and 0 as
    # ``pi.shape_index``.  Either way this is the index.
    member = is_inst & (shape != 0)
    local = dr.select(member, dr.gather(mi.UInt32, scene.reg_local, shape, member), pi.shape_index)
    part_inst = dr.gather(mi.UInt32, scene.first_part, row, is_inst) + local
    part = dr.select(is_inst, part_inst, part_top)
    is_flat = top & (flat >= 0)
    # Masked-off lanes gather 0: keep the divisor ≥ 1 (an integer division by 0 traps on CPUs).
    ntri = dr.maximum(dr.gather(mi.UInt32, parts.triangles, part, is_flat), 1)
    k = dr.select(is_flat, pi.prim_index // ntri, 0)
    row = dr.select(is_flat, dr.gather(mi.UInt32, scene.flat_rows, mi.UInt32(flat) + k, is_flat), row)
    prim = pi.prim_index - k * ntri
    tri = dr.gather(mi.UInt32, parts.face_offset, part, valid) + prim
    return Hit(valid, dr.select(valid, pi.t, dr.inf), row, tri, part, pi.prim_uv.x, pi.prim_uv.y)


def hit_uv(mi: Any, parts: PartArrays, hit: Hit, active: Any) -> Any:
    """Texture coordinates at a hit (barycentric interpolation)."""
    import drjit as dr

    f: Any = dr.gather(mi.Vector3u, parts.faces, hit.tri, active)
    b0 = 1.0 - hit.b1 - hit.b2
    uv0 = dr.gather(mi.Point2f, parts.uv, f.x, active)
    uv1 = dr.gather(mi.Point2f, parts.uv, f.y, active)
    uv2 = dr.gather(mi.Point2f, parts.uv, f.z, active)
    return uv0 * b0 + uv1 * hit.b1 + uv2 * hit.b2


@dataclass
class SurfacePoint:
    """A hit rebuilt in world space."""

    p: Any  # Point3f
    n_geo: Any  # Vector3f, unit, on the shading normal's side
    n_sh: Any  # Vector3f, unit, interpolated shading normal (n_geo where the mesh has none)
    uv: Any  # Point2f
    material: Any  # UInt32


def surface(mi: Any, scene: TraversalScene, parts: PartArrays, hit: Hit, active: Any) -> SurfacePoint:
    """Position, normals, uv and material of a hit from the part buffers and the row's transform."""
    import drjit as dr

    f = dr.gather(mi.Vector3u, parts.faces, hit.tri, active)
    b0 = 1.0 - hit.b1 - hit.b2
    r0 = dr.gather(mi.Vector4f, scene.row_matrix, hit.row * 3 + 0, active)
    r1 = dr.gather(mi.Vector4f, scene.row_matrix, hit.row * 3 + 1, active)
    r2 = dr.gather(mi.Vector4f, scene.row_matrix, hit.row * 3 + 2, active)

    def xform(v: Any) -> Any:
        return mi.Point3f(
            dr.fma(r0.x, v.x, dr.fma(r0.y, v.y, dr.fma(r0.z, v.z, r0.w))),
            dr.fma(r1.x, v.x, dr.fma(r1.y, v.y, dr.fma(r1.z, v.z, r1.w))),
            dr.fma(r2.x, v.x, dr.fma(r2.y, v.y, dr.fma(r2.z, v.z, r2.w))),
        )

    p0 = xform(dr.gather(mi.Point3f, parts.vertices, f.x, active))
    p1 = xform(dr.gather(mi.Point3f, parts.vertices, f.y, active))
    p2 = xform(dr.gather(mi.Point3f, parts.vertices, f.z, active))
    p = p0 * b0 + p1 * hit.b1 + p2 * hit.b2
    ng = dr.normalize(dr.cross(p1 - p0, p2 - p0))
    n_obj = (
        dr.gather(mi.Vector3f, parts.normals, f.x, active) * b0
        + dr.gather(mi.Vector3f, parts.normals, f.y, active) * hit.b1
        + dr.gather(mi.Vector3f, parts.normals, f.z, active) * hit.b2
    )
    q0 = dr.gather(mi.Vector3f, scene.row_normal, hit.row * 3 + 0, active)
    q1 = dr.gather(mi.Vector3f, scene.row_normal, hit.row * 3 + 1, active)
    q2 = dr.gather(mi.Vector3f, scene.row_normal, hit.row * 3 + 2, active)
    ns = mi.Vector3f(dr.dot(q0, n_obj), dr.dot(q1, n_obj), dr.dot(q2, n_obj))
    ln = dr.norm(ns)
    ns = dr.select(ln > 1e-12, ns / dr.maximum(ln, 1e-12), ng)
    # As Mitsuba's meshes: the geometric normal is flipped to the shading normal's side.
    ng = dr.select(dr.dot(ns, ng) < 0.0, -ng, ng)
    uv0 = dr.gather(mi.Point2f, parts.uv, f.x, active)
    uv1 = dr.gather(mi.Point2f, parts.uv, f.y, active)
    uv2 = dr.gather(mi.Point2f, parts.uv, f.z, active)
    uv = uv0 * b0 + uv1 * hit.b1 + uv2 * hit.b2
    material = dr.gather(mi.UInt32, parts.material, hit.part, active)
    return SurfacePoint(p, ng, ns, uv, material)
