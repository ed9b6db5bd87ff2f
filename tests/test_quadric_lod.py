"""Quadric decimation of imported solid parts keeps their shape better than vertex clustering.

No mesh from outside forest ships with the repository or its test dependencies, so the
test mesh is built here: a bent, tapering, knobbly trunk with one limb (tubes with a UV
seam, as modelling tools write them) — the shape forest's own generator does not make.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from forest.library.mesh import MeshData, decimate_to, ply_bytes, quadric_decimate, vertex_normals


def tube(spine: np.ndarray, radius: np.ndarray, sides: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tube along ``spine`` (S, 3) with per-ring ``radius``: vertices, faces (outward), uv (u around, v along).

    The ring's first vertex is repeated at u = 1 (a UV seam: two vertices at one position)."""
    t = np.gradient(spine, axis=0)
    t /= np.linalg.norm(t, axis=1)[:, None]
    nrm = np.cross(t, [1.0, 0.0, 0.0])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    bi = np.cross(t, nrm)
    a = 2 * np.pi * np.arange(sides + 1) / sides
    ring = np.cos(a)[None, :, None] * nrm[:, None] + np.sin(a)[None, :, None] * bi[:, None]
    v = spine[:, None] + radius[:, None, None] * ring
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(spine, axis=0), axis=1))])
    uv = np.stack(np.broadcast_arrays(a[None] / (2 * np.pi), length[:, None]), -1)
    idx = np.arange(v.shape[0] * v.shape[1]).reshape(v.shape[:2])
    a0, b0, a1, b1 = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    f = np.concatenate([np.stack([a0, b0, a1], -1).reshape(-1, 3), np.stack([b0, b1, a1], -1).reshape(-1, 3)])
    if np.dot(np.cross(v[0, 1] - v[0, 0], v[1, 0] - v[0, 0]), ring[0, 0]) < 0:
        f = f[:, ::-1]
    return v.reshape(-1, 3), f, uv.reshape(-1, 2)


def trunk() -> tuple[MeshData, np.ndarray]:
    """The test trunk (~15 000 triangles) and, per vertex, its outward direction (for the normals check)."""
    s = np.linspace(0.0, 1.0, 120)
    spine = np.stack([0.7 * np.sin(2.4 * s) + 0.2 * np.sin(9 * s), 9.0 * s, 0.35 * np.sin(4.0 * s)], 1)
    r = 0.4 * (1 - 0.65 * s) * (1 + 0.1 * np.sin(37 * s))
    s2 = np.linspace(0.0, 1.0, 60)
    limb = spine[70] + np.stack([2.6 * s2, 2.0 * s2 + 0.6 * s2**2, -0.8 * s2 * s2], 1)
    r2 = 0.16 * (1 - 0.6 * s2)
    parts = [tube(spine, r), tube(limb, r2)]
    out, v, f, uv = [], [], [], []
    for (pv, pf, puv), sp in zip(parts, (spine, limb), strict=True):
        f.append(pf + sum(len(x) for x in v))
        v.append(pv)
        uv.append(puv)
        out.append((pv.reshape(len(sp), -1, 3) - sp[:, None]).reshape(-1, 3))
    vv, ff = np.concatenate(v), np.concatenate(f)
    mesh = MeshData(
        vv.astype(np.float32), ff.astype(np.uint32), vertex_normals(vv, ff), np.concatenate(uv).astype(np.float32)
    )
    return mesh, np.concatenate(out)


def surface_error(a: MeshData, b: MeshData, n: int = 20000) -> tuple[float, float]:
    """(mean, max) over both directions of the distance from points sampled on one surface to points densely
    sampled on the other: a symmetric, Hausdorff-like shape error in metres."""
    ta = trimesh.Trimesh(a.vertices, a.faces, process=False)
    tb = trimesh.Trimesh(b.vertices, b.faces, process=False)
    d = []
    for x, y in ((ta, tb), (tb, ta)):
        px = trimesh.sample.sample_surface(x, n, seed=1)[0]
        py = trimesh.sample.sample_surface(y, 8 * n, seed=2)[0]
        d.append(cKDTree(py).query(px)[0])
    both = np.concatenate(d)
    return float(both.mean()), float(both.max())


@pytest.fixture(scope="module")
def source() -> tuple[MeshData, np.ndarray]:
    return trunk()


@pytest.mark.parametrize("target", [300, 1500])
def test_quadric_beats_clustering_at_the_same_budget(source, target: int) -> None:
    mesh, _ = source
    quad = quadric_decimate(mesh, target)
    clus = decimate_to(mesh, target)
    assert quad.triangles <= target and clus.triangles <= target
    # Give clustering the triangles quadric used (or more): the comparison is at the same budget.
    assert clus.triangles <= quad.triangles + target // 20
    q_mean, q_max = surface_error(mesh, quad)
    c_mean, c_max = surface_error(mesh, clus)
    assert q_mean < 0.5 * c_mean, (q_mean, c_mean)
    assert q_max < c_max, (q_max, c_max)


def test_quadric_keeps_uvs_normals_and_is_deterministic(source) -> None:
    mesh, _ = source
    out = quadric_decimate(mesh, 1500)
    assert ply_bytes(out) == ply_bytes(quadric_decimate(mesh, 1500))
    assert np.allclose(np.linalg.norm(out.normals, axis=1), 1.0, atol=1e-5)
    # Normals point out of the tube: compare with the nearest source vertex's outward direction.
    _, nearest = cKDTree(mesh.vertices).query(out.vertices)
    outward = source[1][nearest]
    assert float(np.mean(np.einsum("ij,ij->i", out.normals, outward) > 0)) > 0.98
    # UVs carried over: v (arc length along the stem) matches the nearest source vertex's, and every triangle's
    # u span stays small (a seam is split, not smeared across a triangle).
    assert np.percentile(np.abs(out.uv[:, 1] - mesh.uv[nearest, 1]), 95) < 0.3
    u = out.uv[out.faces.astype(np.int64), 0]
    assert float(np.max(np.ptp(u, axis=1))) < 0.5
    # The two sides of the seam stay separate vertices: u near 0 and near 1 both occur.
    assert (out.uv[:, 0] < 0.05).any() and (out.uv[:, 0] > 0.95).any()


def test_quadric_leaves_small_meshes_alone(source) -> None:
    mesh, _ = source
    assert quadric_decimate(mesh, mesh.triangles) is mesh
