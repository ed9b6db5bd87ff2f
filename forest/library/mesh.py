"""Triangle meshes of the tree library: PLY I/O, normals, bounds and decimation (clustering, quadric).

Every part of a species is stored as a binary little-endian PLY with the
vertex properties ``x y z nx ny nz u v`` (float32) and faces as
``list uchar uint vertex_indices`` — the layout Mitsuba's PLY loader reads
without conversion.  Files are written from numpy buffers with a fixed header
(no comments, no timestamps), so the same arrays give byte-identical files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import ForestError


@dataclass
class MeshData:
    """One triangle mesh as numpy arrays.

    ``vertices (V, 3)`` float32 metres, Y up; ``faces (F, 3)`` uint32;
    ``normals (V, 3)`` float32 unit vectors; ``uv (V, 2)`` float32.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray

    @property
    def triangles(self) -> int:
        """Number of triangles (faces)."""
        return int(len(self.faces))

    def bounds(self) -> np.ndarray:
        """``(2, 3)`` float64 [min, max] of the vertices used by faces (zeros when empty)."""
        return mesh_bounds(self.vertices, self.faces)


def mesh_bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Exact axis-aligned bounds of the referenced vertices, ``(2, 3)`` float64."""
    if len(faces) == 0:
        return np.zeros((2, 3))
    used = np.asarray(vertices, dtype=np.float64)[np.unique(faces)]
    return np.stack([used.min(axis=0), used.max(axis=0)])


def merge_meshes(meshes: list[MeshData]) -> MeshData:
    """Concatenate meshes, offsetting face indices."""
    meshes = [m for m in meshes if len(m.faces)]
    if not meshes:
        return MeshData(
            np.zeros((0, 3), np.float32),
            np.zeros((0, 3), np.uint32),
            np.zeros((0, 3), np.float32),
            np.zeros((0, 2), np.float32),
        )
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return MeshData(
        np.concatenate([m.vertices for m in meshes]).astype(np.float32),
        np.concatenate([m.faces.astype(np.int64) + o for m, o in zip(meshes, offsets)]).astype(np.uint32),
        np.concatenate([m.normals for m in meshes]).astype(np.float32),
        np.concatenate([m.uv for m in meshes]).astype(np.float32),
    )


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals: n_v = normalise(sum over incident faces of (b-a)×(c-a)).

    The cross product's length is twice the face area, so larger faces weigh
    more.  Vertices without a well-defined normal get +Y.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.zeros_like(v)
    if len(f):
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        for k in range(3):
            np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1)
    bad = length < 1e-20
    n[bad] = (0.0, 1.0, 0.0)
    length[bad] = 1.0
    return (n / length[:, None]).astype(np.float32)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised geometric normals ``(b − a) × (c − a)`` of the faces (float64): the winding's normal."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def orient_faces(mesh: MeshData) -> MeshData:
    """Wind every face so its geometric normal agrees with its stored vertex normals.

    A face whose ``(b − a) × (c − a)`` points against the sum of its three
    vertex normals gets the order ``a c b``.  Renderers that take the
    front side from the winding (Cycles, RenderMan, USD's ``orientation``)
    then see the side the normals describe.  Generated meshes are wound right by
    construction; this catches faces that clamping or a tight bend turned over.
    """
    if len(mesh.faces) == 0:
        return mesh
    n = np.asarray(mesh.normals, dtype=np.float64)[np.asarray(mesh.faces, dtype=np.int64)].sum(axis=1)
    bad = np.einsum("ij,ij->i", face_normals(mesh.vertices, mesh.faces), n) < 0
    if not bad.any():
        return mesh
    faces = np.array(mesh.faces, copy=True)
    faces[bad] = faces[bad][:, [0, 2, 1]]
    return MeshData(mesh.vertices, faces, mesh.normals, mesh.uv)


# ---------------------------------------------------------------------------
# PLY
# ---------------------------------------------------------------------------

_VERTEX_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"), ("u", "<f4"), ("v", "<f4")]
)
_FACE_DTYPE = np.dtype([("n", "u1"), ("i", "<u4", (3,))])


def ply_bytes(mesh: MeshData) -> bytes:
    """Serialise ``mesh`` as binary little-endian PLY (deterministic)."""
    nv, nf = len(mesh.vertices), len(mesh.faces)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {nv}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\n"
        "property float u\nproperty float v\n"
        f"element face {nf}\n"
        "property list uchar uint vertex_indices\nend_header\n"
    ).encode("ascii")
    vert = np.empty(nv, dtype=_VERTEX_DTYPE)
    vv = np.asarray(mesh.vertices, dtype=np.float32)
    nn = np.asarray(mesh.normals, dtype=np.float32)
    uu = np.asarray(mesh.uv, dtype=np.float32)
    for i, k in enumerate("xyz"):
        vert[k] = vv[:, i]
        vert["n" + k] = nn[:, i]
    vert["u"] = uu[:, 0]
    vert["v"] = uu[:, 1]
    face = np.empty(nf, dtype=_FACE_DTYPE)
    face["n"] = 3
    face["i"] = np.asarray(mesh.faces, dtype=np.uint32)
    return header + vert.tobytes() + face.tobytes()


def write_ply(path: str | Path, mesh: MeshData) -> Path:
    """Write ``mesh`` to ``path`` atomically."""
    path = Path(path)
    if len(mesh.faces) == 0:
        raise ForestError(f"{path}: refusing to write an empty mesh")
    with atomic_path(path) as tmp:
        tmp.write_bytes(ply_bytes(mesh))
    return path


def read_ply(path: str | Path) -> MeshData:
    """Read a PLY written by :func:`write_ply` (our exact layout) into :class:`MeshData`."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ForestError(f"{path}: cannot read mesh: {e.strerror}") from None
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ForestError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii", "replace").splitlines()
    nv = nf = None
    for line in header:
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            nv = int(parts[2])
        elif parts[:2] == ["element", "face"]:
            nf = int(parts[2])
    expected = ply_bytes(
        MeshData(np.zeros((nv or 0, 3)), np.zeros((nf or 0, 3)), np.zeros((nv or 0, 3)), np.zeros((nv or 0, 2)))
    )[: end + len("end_header\n")]
    body = data[end + len("end_header\n") :]
    if (
        nv is None
        or nf is None
        or data[: end + 11] != expected
        or len(body) != nv * _VERTEX_DTYPE.itemsize + nf * _FACE_DTYPE.itemsize
    ):
        raise ForestError(f"{path}: unexpected PLY layout (expected forest's x y z nx ny nz u v / uint faces)")
    vert = np.frombuffer(body, dtype=_VERTEX_DTYPE, count=nv)
    face = np.frombuffer(body, dtype=_FACE_DTYPE, count=nf, offset=nv * _VERTEX_DTYPE.itemsize)
    return MeshData(
        np.stack([vert["x"], vert["y"], vert["z"]], axis=1).astype(np.float32),
        np.ascontiguousarray(face["i"], dtype=np.uint32),
        np.stack([vert["nx"], vert["ny"], vert["nz"]], axis=1).astype(np.float32),
        np.stack([vert["u"], vert["v"]], axis=1).astype(np.float32),
    )


# ---------------------------------------------------------------------------
# Decimation by vertex clustering
# ---------------------------------------------------------------------------


def cluster_decimate(mesh: MeshData, cell: float) -> MeshData:
    """Vertex clustering (Rossignac & Borrel 1993): snap vertices to a grid of ``cell`` metres.

    Every vertex maps to the cell ``floor((p - min) / cell)``; the cluster's
    representative is the mean of its vertices (position, uv) and the
    re-normalised mean normal.  Faces whose three corners fall into fewer than
    three clusters vanish; duplicate faces are removed.  The result's bounds
    stay within the original's (means of points lie in their convex hull).
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)
    lo = v.min(axis=0)
    key = np.floor((v - lo) / cell).astype(np.int64)
    dims = key.max(axis=0) + 1
    flat = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    uniq, inverse = np.unique(flat, return_inverse=True)
    k = len(uniq)
    counts = np.bincount(inverse, minlength=k).astype(np.float64)[:, None]

    def mean(a):
        out = np.zeros((k, a.shape[1]))
        np.add.at(out, inverse, a)
        return out / counts

    pos = mean(v)
    nrm = mean(np.asarray(mesh.normals, dtype=np.float64))
    ln = np.linalg.norm(nrm, axis=1)
    nrm[ln < 1e-12] = (0.0, 1.0, 0.0)
    ln[ln < 1e-12] = 1.0
    nrm /= ln[:, None]
    uv = mean(np.asarray(mesh.uv, dtype=np.float64))
    f = inverse[np.asarray(mesh.faces, dtype=np.int64)]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    if len(f):
        # Remove duplicates regardless of winding order, keeping first occurrence.
        s = np.sort(f, axis=1)
        _, first = np.unique(s, axis=0, return_index=True)
        f = f[np.sort(first)]
    used, f_new = np.unique(f, return_inverse=True)
    f_new = f_new.reshape(-1, 3)
    return MeshData(
        pos[used].astype(np.float32), f_new.astype(np.uint32), nrm[used].astype(np.float32), uv[used].astype(np.float32)
    )


def decimate_to(mesh: MeshData, target: int, *, tolerance: float = 0.25) -> MeshData:
    """Cluster-decimate ``mesh`` to at most ``target`` triangles (bisection on the cell size).

    Returns the mesh itself when it already has ``target`` triangles or fewer.
    The cell size is bisected on a log scale between 1e-4 and 1 times the
    bounding-box diagonal: a result over ``target`` grows the cell, one under
    ``target·(1 − tolerance)`` shrinks it; the closest result not over
    ``target`` is kept (at most 20 steps).
    """
    if mesh.triangles <= target:
        return mesh
    b = np.asarray(mesh.vertices, dtype=np.float64)
    diag = float(np.linalg.norm(b.max(axis=0) - b.min(axis=0))) or 1.0
    lo, hi = np.log(diag * 1e-4), np.log(diag)
    best = None
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        out = cluster_decimate(mesh, float(np.exp(mid)))
        t = out.triangles
        if t > target:
            lo = mid
            continue
        if best is None or t > best.triangles:
            best = out
        if t >= target * (1 - tolerance):
            break
        hi = mid
    if best is None or best.triangles == 0:
        best = cluster_decimate(mesh, float(np.exp(hi)))
    return best


# ---------------------------------------------------------------------------
# Decimation by quadric error
# ---------------------------------------------------------------------------

#: Corner UVs of one decimated vertex closer than this share of the part's UV extent are merged (averaged);
#: farther ones (the two sides of a UV seam) keep separate vertices.
UV_MERGE = 0.05


def quadric_decimate(mesh: MeshData, target: int) -> MeshData:
    """Decimate ``mesh`` to at most ``target`` triangles by quadric error edge collapses.

    Garland & Heckbert, "Surface Simplification Using Quadric Error Metrics"
    (SIGGRAPH 1997), as implemented by Forstmann's Fast-Quadric-Mesh-Simplification
    (the ``fast-simplification`` package): each collapse removes the edge whose
    merged vertex lies closest, in summed squared plane distance, to the planes
    of the faces it came from, so silhouettes (a trunk's outline, a bend) survive
    far better than under vertex clustering.

    * Vertices at the same position are welded first (files split them at UV
      seams and hard edges; a split would be an open border the collapses must
      work around), so the surface is decimated as one piece.
    * UVs are transferred, not decimated: each output triangle takes the affine
      UV map of the nearest source triangle (by centroid, facing the same way)
      and evaluates it at its corners; a vertex's corners whose UVs agree within
      :data:`UV_MERGE` of the part's UV extent are averaged into one vertex, the
      others (the sides of a seam) stay separate vertices.
    * Normals are the area-weighted vertex normals of the decimated surface.

    Deterministic (no randomness in the collapses, ties broken by index).  Returns
    ``mesh`` itself when it has ``target`` triangles or fewer; falls back to
    :func:`decimate_to` (clustering) for what the collapses cannot bring under
    ``target`` (e.g. many separate small pieces).
    """
    if mesh.triangles <= target:
        return mesh
    import fast_simplification
    from scipy.spatial import cKDTree

    v32 = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    f0 = np.asarray(mesh.faces, dtype=np.int64)
    uv0 = np.asarray(mesh.uv, dtype=np.float64)
    weld, inverse = np.unique(v32, axis=0, return_inverse=True)
    fw = inverse.reshape(-1)[f0]
    fw = fw[(fw[:, 0] != fw[:, 1]) & (fw[:, 1] != fw[:, 2]) & (fw[:, 0] != fw[:, 2])]
    if len(fw) <= target:
        return decimate_to(mesh, target)
    pts, tri = fast_simplification.simplify(weld.astype(np.float64), fw.astype(np.int32), target_count=int(target))
    pts = np.asarray(pts, dtype=np.float64)
    tri = np.asarray(tri, dtype=np.int64)
    if len(tri) == 0:
        return decimate_to(mesh, target)
    # UV transfer: the nearest source triangle facing the same way lends its affine UV map.
    v = v32.astype(np.float64)
    fn_src = face_normals(v, f0)
    fn_out = face_normals(pts, tri)
    k = min(8, len(f0))
    _, near = cKDTree(v[f0].mean(axis=1)).query(pts[tri].mean(axis=1), k=k)
    near = np.asarray(near).reshape(len(tri), k)
    facing = np.einsum("nkj,nj->nk", fn_src[near], fn_out) > 0
    src = near[np.arange(len(tri)), np.where(facing.any(axis=1), facing.argmax(axis=1), 0)]
    a, b, c = (v[f0[src, i]] for i in range(3))
    e1, e2 = b - a, c - a
    g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    det = g11 * g22 - g12 * g12
    ok = det > 1e-12 * np.maximum(g11 * g22, 1e-300)
    det = np.where(ok, det, 1.0)
    ua, ub, uc = (uv0[f0[src, i]] for i in range(3))
    corner_uv = np.empty((len(tri), 3, 2))
    for j in range(3):
        d = pts[tri[:, j]] - a
        d1, d2 = (d * e1).sum(1), (d * e2).sum(1)
        s = np.where(ok, (g22 * d1 - g12 * d2) / det, 1.0 / 3.0)
        t = np.where(ok, (g11 * d2 - g12 * d1) / det, 1.0 / 3.0)
        corner_uv[:, j] = ua + s[:, None] * (ub - ua) + t[:, None] * (uc - ua)
    # One vertex per (decimated vertex, UV cell): corners within a cell are averaged.
    cuv = corner_uv.reshape(-1, 2)
    extent = float(np.max(np.ptp(uv0, axis=0))) if len(uv0) else 0.0
    cell = UV_MERGE * extent if extent > 0 else 1.0
    keys = np.column_stack([tri.reshape(-1), np.floor(cuv / cell).astype(np.int64)])
    uniq, slot = np.unique(keys, axis=0, return_inverse=True)
    slot = slot.reshape(-1)
    count = np.bincount(slot, minlength=len(uniq)).astype(np.float64)[:, None]
    uv_out = np.zeros((len(uniq), 2))
    np.add.at(uv_out, slot, cuv)
    uv_out /= count
    normals = vertex_normals(pts, tri)
    out = MeshData(
        pts[uniq[:, 0]].astype(np.float32),
        slot.reshape(-1, 3).astype(np.uint32),
        normals[uniq[:, 0]],
        uv_out.astype(np.float32),
    )
    return out if out.triangles <= target else decimate_to(out, target)


def components(faces: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of a mesh (faces sharing a vertex): (count, component id per face)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, dtype=np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    g = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    n, label = connected_components(g, directed=False)
    return n, label[f[:, 0]]


def thin_cards(mesh: MeshData, target: int, seed: int, tag: int) -> MeshData | None:
    """Thin a mesh made of many small pieces (leaf cards) to about ``target`` triangles.

    Keeps a random subset of whole pieces and scales each about its centroid by
    ``√(A_all / A_kept)`` so the total area — hence the projected leaf cover —
    is preserved.  Returns None when the mesh is not made of small pieces
    (fewer than 32 pieces, or more than 32 triangles a piece on average).
    """
    n, comp = components(mesh.faces, len(mesh.vertices))
    if n < 32 or mesh.triangles / n > 32:
        return None
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    comp_area = np.bincount(comp, weights=area, minlength=n)
    comp_tris = np.bincount(comp, minlength=n)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, tag])))
    order = rng.permutation(n)
    keep_n = int(np.searchsorted(np.cumsum(comp_tris[order]), target, side="right"))
    keep = np.zeros(n, dtype=bool)
    keep[order[: max(keep_n, 1)]] = True
    s = float(np.sqrt(comp_area.sum() / max(comp_area[keep].sum(), 1e-12)))
    fk = f[keep[comp]]
    used, inv = np.unique(fk, return_inverse=True)
    # Vertex → its piece (via any face using it), centroid of the piece's vertices.
    vcomp = np.empty(len(v), dtype=np.int64)
    vcomp[f.ravel()] = np.repeat(comp, 3)
    cent = np.zeros((n, 3))
    np.add.at(cent, vcomp[used], v[used])
    cnt = np.bincount(vcomp[used], minlength=n).astype(np.float64)
    cent /= np.maximum(cnt, 1)[:, None]
    c = cent[vcomp[used]]
    nv = c + (v[used] - c) * s
    return MeshData(
        nv.astype(np.float32),
        inv.reshape(-1, 3).astype(np.uint32),
        np.asarray(mesh.normals)[used],
        np.asarray(mesh.uv)[used],
    )
