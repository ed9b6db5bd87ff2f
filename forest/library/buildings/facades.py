"""Façade and roof textures the buildings draw themselves (RGB detail factor, alpha 1).

Convention of every library texture (:mod:`forest.library.textures`): RGB is a
linear *detail factor* multiplied by the part's colour.  A façade tile is one
*bay* across and one *floor* high, row 0 at the top of the floor; a roof tile
is mapped from above, ``(u, v) = (x, z)/ROOF_TILE``.
"""

from __future__ import annotations

import numpy as np

PLAIN_UV = (0.02, 0.02)  # a texel of plain wall in every façade tile
TEX_SIZE = 64
ROOF_TILE = {"tower": 6.0, "apartment": 6.0, "house": 2.0, "warehouse": 3.0}  # metres a roof texture tile

GLASS = ((0.16, 0.21, 0.28), (0.15, 0.22, 0.2), (0.24, 0.2, 0.16), (0.19, 0.19, 0.2))  # blue, green, bronze, grey


def facade_rgba(btype: str, n: int = TEX_SIZE, *, glass=GLASS[0], band: float = 0.28) -> np.ndarray:
    """One façade tile, ``(n, n, 4)`` float32: one bay across (``u``), one floor down (``t`` from the top).

    ``glass`` is the glazing's detail colour (each seed picks one of :data:`GLASS`).

    * ``tower`` — a window band: glass over ``t ∈ [band, 0.92]`` across the whole
      bay (reflection brightening towards its top), a mullion at each edge.
    * ``apartment`` — a framed window ``u ∈ [0.2, 0.8]``, ``t ∈ [0.25, 0.85]``
      with a lighter frame and a sill shadow.
    * ``house`` — a smaller window with a lintel, ``u ∈ [0.32, 0.68]``.
    * ``warehouse`` — ribbed cladding ``0.86 + 0.1·cos(2π·10u)`` with a high
      window band at ``t ∈ [0.08, 0.2]``.

    The top-left corner (``u, t < 0.06``) is plain wall in every tile.
    """
    c = (np.arange(n) + 0.5) / n
    t, u = np.meshgrid(c, c, indexing="ij")
    rgb = np.ones((n, n, 3))
    glass = np.asarray(glass, dtype=np.float64)

    def rect(u0, u1, t0, t1):
        return (u >= u0) & (u < u1) & (t >= t0) & (t < t1)

    if btype == "tower":
        rgb[:] = 0.92
        glazed = rect(0.0, 1.0, band, 0.92)
        refl = 1.0 + 0.4 * np.clip((0.92 - t) / (0.92 - band), 0, 1) ** 2
        rgb[glazed] = glass[None, :] * refl[glazed][:, None]
        mull = glazed & ((u < 0.06) | (u >= 0.94) | (np.abs(u - 0.5) < 0.02))
        mull &= ~((u < 0.06) & (t < 0.06))
        rgb[mull] = 0.55
    elif btype == "apartment":
        rgb[:] = 0.95
        frame = rect(0.18, 0.82, 0.23, 0.87)
        win = rect(0.22, 0.78, 0.27, 0.83)
        rgb[frame] = 0.75
        rgb[win] = glass * 1.2
        rgb[rect(0.48, 0.52, 0.27, 0.83)] = 0.7
        rgb[rect(0.16, 0.84, 0.87, 0.92)] = 0.6  # sill shadow
    elif btype == "house":
        rgb[:] = 0.97
        rgb[rect(0.29, 0.71, 0.2, 0.26)] = 0.7  # lintel
        rgb[rect(0.3, 0.7, 0.28, 0.8)] = 0.85  # frame
        rgb[rect(0.33, 0.67, 0.31, 0.77)] = glass * 1.3
        rgb[rect(0.49, 0.51, 0.31, 0.77)] = 0.85  # glazing bar
        rgb[rect(0.28, 0.72, 0.8, 0.84)] = 0.65  # sill
    elif btype == "warehouse":
        rib = 0.86 + 0.1 * np.cos(2 * np.pi * 10 * u)
        rgb[:] = rib[..., None]
        rgb[rect(0.06, 0.94, 0.08, 0.2)] = glass * 1.6
        rgb[t >= 0.96] = 0.6  # plinth line
        rgb[(u < 0.06) & (t < 0.06)] = 0.9
    else:
        raise ValueError(btype)
    out = np.ones((n, n, 4), dtype=np.float32)
    out[..., :3] = np.clip(rgb, 0.0, 1.0)
    return out


def roof_rgba(btype: str, n: int = TEX_SIZE) -> np.ndarray:
    """One roof tile, ``(n, n, 4)`` float32, mapped from above: ``(u, v) = (x, z)/ROOF_TILE``.

    * ``house`` — six courses of tiles: each course darkens towards its lower
      edge, ``0.72 + 0.28·(1 − f)^0.5`` with ``f`` the position within the
      course, and staggered joints every quarter tile.
    * ``warehouse`` — corrugated sheet, ribs along X: ``0.84 + 0.12·cos(2π·8v)``.
    * ``tower``, ``apartment`` — a membrane in panels: seams ``0.8`` on the
      panel edges, ``0.93`` inside.
    """
    c = (np.arange(n) + 0.5) / n
    v, u = np.meshgrid(c, c, indexing="ij")
    if btype == "house":
        course = v * 6.0
        f = course - np.floor(course)
        d = 0.72 + 0.28 * np.sqrt(1.0 - f)
        stagger = (np.floor(course) % 2) * 0.125
        joint = np.abs(((u + stagger) * 4.0) % 1.0 - 0.5) > 0.47
        d = np.where(joint, d * 0.8, d)
    elif btype == "warehouse":
        d = 0.84 + 0.12 * np.cos(2 * np.pi * 8 * v)
    elif btype in ("tower", "apartment"):
        seam = (np.minimum(u, 1 - u) < 0.02) | (np.minimum(v, 1 - v) < 0.02)
        d = np.where(seam, 0.8, 0.93)
    else:
        raise ValueError(btype)
    out = np.ones((n, n, 4), dtype=np.float32)
    out[..., :3] = np.clip(d, 0.0, 1.0)[..., None]
    return out
