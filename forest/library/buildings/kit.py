"""The mesh kit of the buildings: flat-shaded polygons of one material, boxes, façade boxes, parapets.

Geometry is built from axis-aligned boxes and flat quads, Y up, metres, the
footprint centred on the origin and the base at ``y = 0`` (no floor faces on
the ground).  Polygons are given counter-clockwise seen from outside, so the
winding's normal is the outward normal stored with the vertices.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from ..mesh import MeshData
from .facades import PLAIN_UV


class PartMesh:
    """Quads and triangles of one material, collected then merged into one :class:`MeshData`."""

    def __init__(self, planar: float | None = None):
        self.planar = planar  # texture coordinates projected from above, ``(x, z)/planar``
        self.pos: list[np.ndarray] = []
        self.uv: list[np.ndarray] = []
        self.nv: list[int] = []

    def polys(self, p: np.ndarray, uv: np.ndarray | None = None) -> None:
        """Add ``N`` planar polygons ``p (N, k, 3)`` (k = 3 or 4, counter-clockwise from outside)."""
        p = np.asarray(p, dtype=np.float64)
        if p.size == 0:
            return
        if self.planar:
            uv = p[..., [0, 2]] / self.planar
        elif uv is None:
            uv = np.broadcast_to(np.array(PLAIN_UV), p.shape[:2] + (2,))
        self.pos.append(p)
        self.uv.append(np.broadcast_to(np.asarray(uv, dtype=np.float64), p.shape[:2] + (2,)))
        self.nv.append(p.shape[1])

    def mesh(self) -> MeshData:
        """Flat-shaded mesh: each polygon its own vertices; a quad is two triangles.

        Normals: ``(p₁−p₀)×(p₂−p₀)`` for a triangle, ``(p₂−p₀)×(p₃−p₁)`` (the
        diagonals) for a quad, normalised; a degenerate polygon gets +Y.
        """
        vs, ns, us, fs = [], [], [], []
        off = 0
        for p, uv, k in zip(self.pos, self.uv, self.nv):
            n = np.cross(p[:, 1] - p[:, 0], p[:, k - 1] - p[:, 0])
            if k == 4:  # a quad's normal from both diagonals (robust to a degenerate corner)
                n = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
            ln = np.linalg.norm(n, axis=1, keepdims=True)
            n = np.where(ln > 1e-12, n / np.maximum(ln, 1e-12), np.array([0.0, 1.0, 0.0]))
            N = len(p)
            tmpl = np.array([[0, 1, 2]]) if k == 3 else np.array([[0, 1, 2], [0, 2, 3]])
            fs.append((tmpl[None] + (off + k * np.arange(N))[:, None, None]).reshape(-1, 3))
            vs.append(p.reshape(-1, 3))
            ns.append(np.repeat(n, k, axis=0))
            us.append(uv.reshape(-1, 2))
            off += k * N
        if not vs:
            return MeshData(
                np.zeros((0, 3), np.float32),
                np.zeros((0, 3), np.uint32),
                np.zeros((0, 3), np.float32),
                np.zeros((0, 2), np.float32),
            )
        return MeshData(
            np.concatenate(vs).astype(np.float32),
            np.concatenate(fs).astype(np.uint32),
            np.concatenate(ns).astype(np.float32),
            np.concatenate(us).astype(np.float32),
        )


def box_faces(lo: ArrayLike, hi: ArrayLike, *, top: bool = True, bottom: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Faces of ``N`` axis-aligned boxes ``[lo, hi]``: sides (+X, −X, +Z, −Z) then top, bottom.

    Returns ``(quads (N, F, 4, 3), widths (N, F))``; each side quad runs
    bottom-left, bottom-right, top-right, top-left seen from outside, so its
    outward normal is ``(p₁−p₀)×(p₃−p₀)``.
    """
    lo = np.atleast_2d(np.asarray(lo, dtype=np.float64))
    hi = np.atleast_2d(np.asarray(hi, dtype=np.float64))
    x0, y0, z0 = lo.T
    x1, y1, z1 = hi.T

    def P(x, y, z):
        return np.stack(np.broadcast_arrays(x, y, z), axis=-1)

    faces = [
        np.stack([P(x1, y0, z1), P(x1, y0, z0), P(x1, y1, z0), P(x1, y1, z1)], axis=1),  # +X
        np.stack([P(x0, y0, z0), P(x0, y0, z1), P(x0, y1, z1), P(x0, y1, z0)], axis=1),  # −X
        np.stack([P(x0, y0, z1), P(x1, y0, z1), P(x1, y1, z1), P(x0, y1, z1)], axis=1),  # +Z
        np.stack([P(x1, y0, z0), P(x0, y0, z0), P(x0, y1, z0), P(x1, y1, z0)], axis=1),  # −Z
    ]
    widths = [z1 - z0, z1 - z0, x1 - x0, x1 - x0]
    if top:
        faces.append(np.stack([P(x0, y1, z1), P(x1, y1, z1), P(x1, y1, z0), P(x0, y1, z0)], axis=1))
        widths.append(x1 - x0)
    if bottom:
        faces.append(np.stack([P(x0, y0, z0), P(x1, y0, z0), P(x1, y0, z1), P(x0, y0, z1)], axis=1))
        widths.append(x1 - x0)
    return np.stack(faces, axis=1), np.stack(widths, axis=1)


def add_boxes(part: PartMesh, lo, hi, *, top: bool = True, bottom: bool = False) -> None:
    """Boxes with plain texture coordinates (parapets, plant, trim)."""
    q, _ = box_faces(lo, hi, top=top, bottom=bottom)
    part.polys(q.reshape(-1, 4, 3))


def add_facade_boxes(walls: PartMesh, roof: PartMesh | None, lo, hi, bay: float, floor_h: float) -> None:
    """Building masses: four textured walls (whole tiles across, floors up) and a flat roof."""
    q, w = box_faces(lo, hi, top=False)
    sides = q.reshape(-1, 4, 3)
    n = np.maximum(1.0, np.round(w.reshape(-1) / bay))
    vb = -sides[:, 0, 1] / floor_h
    vt = -sides[:, 2, 1] / floor_h
    uv = np.stack(
        [
            np.stack([np.zeros_like(n), vb], -1),
            np.stack([n, vb], -1),
            np.stack([n, vt], -1),
            np.stack([np.zeros_like(n), vt], -1),
        ],
        axis=1,
    )
    walls.polys(sides, uv)
    if roof is not None:
        tq, _ = box_faces(lo, hi, top=True)
        roof.polys(tq[:, 4])


def parapets(part: PartMesh, x0, z0, x1, z1, y, height: float, t: float = 0.3) -> None:
    """A ring of four low walls of thickness ``t`` on the roof edge ``[x0, x1] × [z0, z1]`` at height ``y``."""
    if height <= 0:
        return
    lo = np.array([[x0, y, z1 - t], [x0, y, z0], [x0, y, z0 + t], [x1 - t, y, z0 + t]])
    hi = np.array(
        [[x1, y + height, z1], [x1, y + height, z0 + t], [x0 + t, y + height, z1 - t], [x1, y + height, z1 - t]]
    )
    add_boxes(part, lo, hi)


def far_box(W: float, D: float, h: float, h_wall: float | None = None) -> tuple[MeshData, MeshData]:
    """The far level: walls and roof of one ``W × D × h`` box standing on the origin.

    With ``h_wall < h`` (a pitched roof) the sides above ``h_wall`` belong to
    the roof, so the box keeps the roof's colour where the building shows it.
    """
    h_wall = h if h_wall is None else min(h_wall, h)
    q, _ = box_faces([-W / 2, 0.0, -D / 2], [W / 2, h_wall, D / 2], top=False)
    walls, roof = PartMesh(), PartMesh()
    walls.polys(q[0])
    if h_wall < h:
        q2, _ = box_faces([-W / 2, h_wall, -D / 2], [W / 2, h, D / 2])
        roof.polys(q2[0])
    else:
        q2, _ = box_faces([-W / 2, 0.0, -D / 2], [W / 2, h, D / 2])
        roof.polys(q2[0, 4:])
    return walls.mesh(), roof.mesh()
