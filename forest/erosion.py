"""Eroded relief: gullies and spurs running down the far hills' slopes.

The hills of :mod:`forest.skirt` ("Hills") are a squared fractional Brownian
motion of value noise: from a few kilometres they read as smooth domes and
cones.  Real mountains are cut by water: every slope is furrowed by gullies
that run down the fall line and branch toward the crests, with spurs between
them, so a sunlit face shows a comb of light and shade.  This module adds
that furrowing to a height field h as a sum of oriented cosines, the kernel of
sparse Gabor noise (Lagae, Lefebvre, Drettakis & Dutré 2009, "Procedural noise
using sparse Gabor convolution", ACM TOG 28(3): 54) turned so that its stripes
run along the local fall line instead of a fixed direction:

    G_o(p) = Σ_c w_c cos(2π (f_o p − c)·t̂) / Σ_c w_c,    w_c = exp(−2 |f_o p − c|²)

over the 3×3 cells around f_o·p (unit cells, each with its point c placed
within the cell's middle half by a hash of the cell and the octave), with t̂ = ∇ℓ^⊥ / |∇ℓ| the
contour direction of a smoothed field ℓ (the hills' three coarsest octaves):
a cosine of the distance across the fall line is constant along it, so each
cell draws straight furrows down the slope, and where the slope turns around
a peak the furrows of neighbouring cells fan out from it as drainage does.
Three octaves, f_o = 2^o·:data:`GULLY_FREQUENCY` per hill scale (a gully
every L/8, L/16, L/32), amplitudes halving from :data:`GULLY_DEPTH`:

    h' = h + e · s(|∇(A ℓ)| / σ) · Σ_o ½^o · GULLY_DEPTH · G_o,    s(t) = min(t, 1)²(3 − 2 min(t, 1))

with e ∈ [0, 1] the ``erosion`` setting and A the hills' height: the
gullies fade out where the ground is level (slope below σ =
:data:`GULLY_SLOPE`), so plains and valley floors stay smooth and steep
faces are furrowed most.  The gradient of ℓ is taken by central differences
(±L/200).  Deterministic: hashes of the lattice, the hills' seed and a
purpose tag, no random state.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .scatter.canopy import lattice_at

#: Gullies per hill scale L in the coarsest octave (a gully every L/8).
GULLY_FREQUENCY = 8.0
#: Depth of the coarsest octave's gullies at ``erosion`` 1, as a share of the hills' height A.
GULLY_DEPTH = 0.06
#: Octaves of gullies (frequency doubling, depth halving).
GULLY_OCTAVES = 3
#: Slope (rise over run) above which the gullies are cut at full depth.
GULLY_SLOPE = 0.3
#: Octaves of the smoothed field whose fall line the gullies follow.
FLOW_OCTAVES = 3
#: Purpose tag of the gullies' hashes (a constant per purpose, CONTRIBUTING's seeding rule).
GULLY_TAG = 0x4755_4C4C


def gabor_along(u: np.ndarray, v: np.ndarray, tu: np.ndarray, tv: np.ndarray, key: np.uint64) -> np.ndarray:
    """G(u, v) ∈ [−1, 1]: the module docstring's sum of cosines across the direction (tu, tv) (unit), over the 3×3
    jittered unit cells around (u, v)."""
    iu, iv = np.floor(u), np.floor(v)
    total = np.zeros(np.shape(u))
    weight = np.zeros(np.shape(u))
    jitter = np.uint64((int(key) ^ 0x5851_F42D_4C95_7F2D) % 2**64)
    # The cells' jitter hashed once per cell of the points' bounding box (one ring of cells around it), then
    # gathered by a flat index: the same values as lattice() per point.
    lo_u, lo_v = int(iu.min(initial=0.0)) - 1, int(iv.min(initial=0.0)) - 1
    width = int(iu.max(initial=0.0)) + 2 - lo_u
    cells_u = np.arange(lo_u, lo_u + width + 1, dtype=np.int64)[None, :]
    cells_v = np.arange(lo_v, int(iv.max(initial=0.0)) + 3, dtype=np.int64)[:, None]
    ju, jv = lattice_at(cells_u, cells_v, key).ravel(), lattice_at(cells_u, cells_v, jitter).ravel()
    base = (iv.astype(np.int64) - lo_v) * (width + 1) + (iu.astype(np.int64) - lo_u)
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            cell = base + (dj * (width + 1) + di)
            du = u - (iu + (di + 0.25) + 0.5 * ju[cell])
            dv = v - (iv + (dj + 0.25) + 0.5 * jv[cell])
            w = np.exp(-2.0 * (du * du + dv * dv))
            total += w * np.cos(2.0 * np.pi * (du * tu + dv * tv))
            weight += w
    return total / weight


def gullies(
    x: np.ndarray,
    z: np.ndarray,
    smooth: Callable[[np.ndarray, np.ndarray], np.ndarray],
    height: float,
    scale: float,
    seed: int,
) -> np.ndarray:
    """The module docstring's furrows at world points (x, z), in units of the hills' height A (add e times this to
    h): ``smooth(x, z)`` is ℓ ∈ [0, 1], the smoothed field whose fall line they follow, ``height`` A and ``scale``
    L in metres."""
    x = np.asarray(x, np.float64)
    z = np.asarray(z, np.float64)
    eps = float(scale) / 200.0
    gx = (smooth(x + eps, z) - smooth(x - eps, z)) * (float(height) / (2.0 * eps))
    gz = (smooth(x, z + eps) - smooth(x, z - eps)) * (float(height) / (2.0 * eps))
    slope = np.hypot(gx, gz)
    t = np.minimum(slope / GULLY_SLOPE, 1.0)
    gate = t * t * (3.0 - 2.0 * t)
    tu, tv = -gz / np.maximum(slope, 1e-12), gx / np.maximum(slope, 1e-12)
    u, v = x / float(scale), z / float(scale)
    key = np.uint64((int(seed) * 0x9E3779B97F4A7C15 + GULLY_TAG) % 2**64)
    total = np.zeros(np.shape(x))
    for octave in range(GULLY_OCTAVES):
        f = GULLY_FREQUENCY * 2.0**octave
        k = np.uint64((int(key) + octave * 0xBF58476D1CE4E5B9) % 2**64)
        total += 0.5**octave * gabor_along(u * f, v * f, tu, tv, k)
    return GULLY_DEPTH * gate * total
