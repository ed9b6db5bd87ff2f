"""The ground to the horizon: a skirt around the terrain, and an albedo grid that fades on it.

**Skirt.**  A terrain ends at its extent; past it a camera saw the sky below
the horizon (a hard horizon line, a dark band, a city floating on a square).
:func:`skirt_mesh` extrudes every boundary edge of the terrain mesh (an edge
used by one face) outward, radially from the centre of the extent, to a ring
of radius R, and lowers or raises that ring to the mean height of the
boundary:

    v' = c + (v − c)_xz · R / |v − c|_xz,   y' = mean(y of the boundary vertices)

so the ground runs on from its own edge height and becomes one level plane
far away (a slope of (ȳ − y)/(R − r), a fraction of a degree).  A first,
narrow band level with the edge turns the shading normal from the terrain's
own to +Y (interpolating a tilted edge normal over the whole long band drew
stripes to the horizon); its faces wind upward.  R (:func:`skirt_radius`) reaches the camera's far clip
or at least :data:`MIN_SKIRT_RADIUS` metres (and 20 terrain widths): from
hundreds of metres up the ring lies a fraction of a pixel below the horizon.

**Fade.**  With the skirt, the ground's albedo grid (the Scene's
``terrain_albedo``, :mod:`forest.ground`) is padded so that past the terrain's
edge it fades to its mean colour (:func:`fade_beyond_edge`): clamped lookups
would otherwise repeat every border texel outward as a stripe running to the
horizon.  Both renderers use these; the exporters write the terrain alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Smallest radius of the skirt, metres.
MIN_SKIRT_RADIUS = 30_000.0
#: The skirt reaches at least this many terrain widths from the centre.
SKIRT_WIDTHS = 20.0
#: Width of the skirt's first band, as a fraction of the terrain's width: its normal turns up over it.
SKIRT_RAMP = 0.03


def skirt_radius(extent, far: float) -> float:
    """R: the camera's far clip, at least :data:`MIN_SKIRT_RADIUS` and :data:`SKIRT_WIDTHS` terrain widths."""
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    size = max(xmax - xmin, zmax - zmin, 1.0)
    return float(max(far, MIN_SKIRT_RADIUS, SKIRT_WIDTHS * size))


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) vertex pairs of the edges used by exactly one face, in the direction their face runs them."""
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return e[counts[inverse.ravel()] == 1]


@dataclass(frozen=True)
class Skirt:
    """The skirt as a mesh: ``vertices`` (V, 3), ``faces`` (F, 3), ``normals`` (V, 3); ``uv`` as set by the caller."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None = None


def skirt_mesh(terrain, radius: float) -> Skirt | None:
    """The skirt around ``terrain`` (see the module docstring); None for a terrain without a boundary.

    Two bands per boundary edge: a short one (:data:`SKIRT_RAMP` of the terrain's width, level with the edge)
    over which the shading normal turns from the terrain's to +Y, then the long one out to ``radius``.
    """
    v = np.asarray(terrain.vertices, np.float64)
    edges = boundary_edges(terrain.faces)
    if len(edges) == 0:
        return None
    used = np.unique(edges)
    xmin, zmin, xmax, zmax = terrain.extent
    c = np.array([(xmin + xmax) / 2.0, (zmin + zmax) / 2.0])
    inner = v[used]
    rel = inner[:, [0, 2]] - c
    dist = np.maximum(np.linalg.norm(rel, axis=1), 1e-9)
    unit = rel / dist[:, None]
    ramp = max(SKIRT_RAMP * max(xmax - xmin, zmax - zmin), 1.0)
    mid = inner.copy()
    mid[:, [0, 2]] = inner[:, [0, 2]] + unit * ramp
    outer = np.empty_like(inner)
    outer[:, [0, 2]] = c + unit * max(float(radius), float(dist.max()) + 2.0 * ramp)
    outer[:, 1] = inner[:, 1].mean()
    k = len(used)
    local = np.searchsorted(used, edges)  # boundary vertex → 0..k-1
    a, b = local[:, 0], local[:, 1]
    faces = np.concatenate(
        [
            np.stack([a, b, b + k], 1),
            np.stack([a, b + k, a + k], 1),
            np.stack([a + k, b + k, b + 2 * k], 1),
            np.stack([a + k, b + 2 * k, a + 2 * k], 1),
        ]
    )
    verts = np.concatenate([inner, mid, outer])
    # Wind every face upward (+Y) whatever the terrain's own winding.
    p0, p1, p2 = (verts[faces[:, i]] for i in range(3))
    down = np.cross(p1 - p0, p2 - p0)[:, 1] < 0
    faces[down] = faces[down][:, [0, 2, 1]]
    up = np.tile([0.0, 1.0, 0.0], (2 * k, 1))
    normals = np.concatenate([np.asarray(terrain.vertex_normals, np.float64)[used], up])
    return Skirt(verts.astype(np.float32), faces.astype(np.uint32), normals.astype(np.float32))


#: Texels added around an albedo grid by :func:`fade_beyond_edge`, as a share of its longer side (at most
#: :data:`FADE_MAX_TEXELS`).
FADE_SHARE = 0.125
FADE_MAX_TEXELS = 128


def fade_beyond_edge(rgb: np.ndarray, extent) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """An (H, W, 3) albedo grid padded so that the ground past the terrain's edge fades to its mean colour.

    A grid looked up with edge clamping repeats its border texels outward, so
    on the skirt every border texel becomes a stripe running to the horizon
    (toward the vanishing point).  This adds P = ⌈FADE_SHARE · max(H, W)⌉
    texels (≤ FADE_MAX_TEXELS) on every side, of the same size as the grid's,
    whose colour blends from the clamped border texel to the grid's mean ρ̄:

        ρ(d) = (1 − s(d/P))·ρ_edge + s(d/P)·ρ̄,    s(t) = t²(3 − 2t)

    with d the distance in texels past the edge; the outermost ring is ρ̄, so
    everything beyond it is one colour.  The grid inside is untouched, and
    the extent grows by P texels on every side.  Returns the grid and its
    extent (xmin, zmin, xmax, zmax).
    """
    rgb = np.asarray(rgb, np.float32)
    h, w = rgb.shape[:2]
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    if h * w <= 1:
        return rgb, (xmin, zmin, xmax, zmax)
    p = int(min(FADE_MAX_TEXELS, max(2, np.ceil(FADE_SHARE * max(h, w)))))
    padded = np.pad(rgb, ((p, p), (p, p), (0, 0)), mode="edge")
    rows = np.arange(h + 2 * p)
    cols = np.arange(w + 2 * p)
    dr = np.maximum(np.maximum(p - rows, rows - (h + p - 1)), 0)
    dc = np.maximum(np.maximum(p - cols, cols - (w + p - 1)), 0)
    t = np.clip(np.maximum(dr[:, None], dc[None, :]) / p, 0.0, 1.0)
    s = (t * t * (3.0 - 2.0 * t))[..., None]
    mean = rgb.reshape(-1, rgb.shape[2]).mean(axis=0)
    out = ((1.0 - s) * padded + s * mean).astype(np.float32)
    dx, dz = (xmax - xmin) / w, (zmax - zmin) / h
    return out, (xmin - p * dx, zmin - p * dz, xmax + p * dx, zmax + p * dz)
