"""Leaf textures the project draws itself: RGBA masks for alpha-tested leaf cards.

Convention for every texture of the library: the RGB channels hold a
*detail factor* (linear, mostly 0.7–1.0: veins and edges slightly darker) and
alpha holds the card mask.  A renderer's leaf reflectance is therefore
``part.colour × texture.rgb × tint`` and its opacity is ``texture.alpha``.
Images are written as sRGB-encoded 8-bit PNG with *straight* (unassociated)
alpha, as PNG defines it (:func:`write_texture`); read them with
``forest.images.read_image(path, unassociated=True)`` and sRGB-decode the RGB
(OpenImageIO's default read multiplies RGB by alpha, darkening card edges).

Card UV layout: ``u ∈ [0, 1]`` across the leaf, ``v ∈ [0, 1]`` from the stalk
to the tip.  The shapes are symmetric under ``v → 1 − v`` so a renderer that
flips the image vertically still sees the same leaf.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..images import write_image

SHAPES = ("broad", "needle", "frond", "blade", "fern")
SIZE = 256


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres: ``x ∈ (-1, 1)`` across, ``t ∈ (0, 1)`` along the card."""
    c = (np.arange(n) + 0.5) / n
    t, x = np.meshgrid(c, 2.0 * c - 1.0, indexing="ij")
    return x, t


def _smooth_mask(sd: np.ndarray, n: int) -> np.ndarray:
    """Anti-aliased coverage from a signed distance (negative inside), one pixel wide edge."""
    return np.clip(0.5 - sd * n / 2.0, 0.0, 1.0)


def leaf_rgba(shape: str, n: int = SIZE) -> np.ndarray:
    """Draw a leaf card texture, ``(n, n, 4)`` float32 (RGB detail, alpha mask).

    * ``broad`` — a lens-shaped blade: half-width ``w(t) = 0.92·sin(πt)^0.8``
      (a Gielis-like superellipse), with a midrib and pinnate veins at ±40°.
    * ``needle`` — a fan of 16 needles radiating from the card's centre.
    * ``frond`` — a narrow leaflet, ``w(t) = 0.45·sin(πt)``.
    * ``blade`` — three grass blades, each ``w = 0.12·sin(πt)^0.5``.
    * ``fern`` — a pinna: central rachis with alternating lobes.
    """
    x, t = _grid(n)
    ax = np.abs(x)
    detail = np.ones((n, n), dtype=np.float64)
    if shape == "broad":
        w = 0.92 * np.sin(np.pi * t) ** 0.8
        alpha = _smooth_mask(ax - w, n)
        rib = np.exp(-((x / 0.025) ** 2))
        # Veins: lines ax = (t - t0)·tan(50°) mirrored about the centre of the card.
        phase = (np.abs(t - 0.5) * 2.0 + ax * 0.85) * 7.0
        veins = np.exp(-(((phase - np.round(phase)) / 0.06) ** 2)) * (ax < w * 0.9)
        detail = 0.92 - 0.18 * rib - 0.10 * veins + 0.08 * (ax / np.maximum(w, 1e-3)).clip(0, 1) ** 2
    elif shape == "needle":
        # Nine needles from the centre (0, 0.5), angles spread over 360°.
        cx, cy = x, (t - 0.5) * 2.0
        r = np.hypot(cx, cy)
        ang = np.arctan2(cy, cx)
        k = 16
        sector = (ang / (2 * np.pi) * k) % 1.0 - 0.5
        dist = np.abs(sector) * 2 * np.pi / k * r
        alpha = _smooth_mask(dist - 0.05 * (1.0 - 0.6 * r), n) * (r < 0.95)
        detail = 0.85 + 0.15 * r
    elif shape == "frond":
        w = 0.45 * np.sin(np.pi * t)
        alpha = _smooth_mask(ax - w, n)
        detail = 0.9 - 0.2 * np.exp(-((x / 0.04) ** 2)) + 0.1 * (ax / np.maximum(w, 1e-3)).clip(0, 1)
    elif shape == "blade":
        alpha = np.zeros_like(x)
        for c, s in ((-0.55, 0.9), (0.0, 1.0), (0.55, 0.85)):
            w = 0.12 * np.sin(np.pi * np.clip(t / s, 0, 1)) ** 0.5 * (t < s)
            alpha = np.maximum(alpha, _smooth_mask(np.abs(x - c) - w, n))
        detail = 0.85 + 0.15 * t
    elif shape == "fern":
        rachis = _smooth_mask(ax - 0.03, n)
        # Lobes: ellipses centred on the rachis every 1/7 of the length, alternating sides.
        k = 7
        seg = t * k
        idx = np.floor(seg)
        side = np.where(idx % 2 == 0, 1.0, -1.0)
        lt = seg - idx - 0.5  # -0.5..0.5 within a lobe
        taper = np.sin(np.pi * t) ** 0.6
        lx = (x * side - 0.42 * taper) / (0.42 * taper + 1e-3)
        lobe = _smooth_mask(np.hypot(lx, lt / 0.5) - 1.0, n / 6)
        lobe2 = _smooth_mask(
            np.hypot((-x * side - 0.42 * taper) / (0.42 * taper + 1e-3), (((seg + 0.5) % 1.0) - 0.5) / 0.5) - 1.0, n / 6
        )
        alpha = np.maximum(rachis, np.maximum(lobe, lobe2)) * (t > 0.02) * (t < 0.98)
        detail = 0.88 - 0.15 * np.exp(-((x / 0.05) ** 2)) + 0.1 * ax
    else:
        raise ValueError(f"unknown leaf shape {shape!r}")
    rgba = np.empty((n, n, 4), dtype=np.float32)
    rgba[..., :3] = np.clip(detail, 0.0, 1.0)[..., None]
    rgba[..., 3] = np.clip(alpha, 0.0, 1.0)
    # A faint warm/cool shift across the blade keeps the detail from looking flat grey.
    rgba[..., 0] *= 0.97 + 0.03 * t
    rgba[..., 2] *= 0.97 + 0.03 * (1.0 - t)
    return rgba


def coverage(shape: str) -> float:
    """Mean alpha of the shape: the share of a card that is leaf."""
    return float(leaf_rgba(shape, 128)[..., 3].mean())


def write_texture(path: str | Path, rgba: np.ndarray) -> Path:
    """Write linear straight-alpha RGBA as an sRGB PNG that keeps straight alpha (atomic, deterministic)."""
    return write_image(path, rgba, attributes={"oiio:UnassociatedAlpha": 1})


def read_texture(path: str | Path) -> np.ndarray:
    """Read a texture as linear RGB + straight alpha, float32 ``(H, W, 4)`` (alpha 1 when absent)."""
    from ..images import read_image, srgb_to_linear

    img = read_image(path, what="texture", unassociated=True)
    c = img.shape[2]
    out = np.ones(img.shape[:2] + (4,), dtype=np.float32)
    out[..., :3] = srgb_to_linear(img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2))
    if c in (2, 4):
        out[..., 3] = img[..., c - 1]
    return out


def write_leaf_texture(path: str | Path, shape: str) -> Path:
    """Draw ``shape`` and write it as an RGBA PNG (atomic, deterministic)."""
    return write_texture(path, leaf_rgba(shape))


CLUSTER_TAG = 0xC1


def cluster_rgba(shape: str, n: int = SIZE, leaves: int = 14) -> np.ndarray:
    """A card holding several leaves of ``shape``, for the lower levels of detail.

    Leaf ``i`` is the single-leaf texture mapped into the card by a rotation
    ``R(a_i)``, scale ``s_i`` and centre ``c_i`` drawn from a fixed stream
    (inverse-mapped nearest-texel lookup); later leaves cover earlier ones.
    """
    leaf = leaf_rgba(shape, n)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([CLUSTER_TAG, SHAPES.index(shape)])))
    c = (np.arange(n) + 0.5) / n
    py, px = np.meshgrid(c, c, indexing="ij")
    out = np.zeros((n, n, 4), dtype=np.float32)
    out[..., :3] = 1.0
    for i in range(leaves):
        ang = rng.uniform(0, 2 * np.pi) if i else 0.0
        s = rng.uniform(0.3, 0.42)
        cx, cy = (0.5, 0.5) if i == 0 else rng.uniform(0.22, 0.78, 2)
        dx, dy = px - cx, py - cy
        lu = (np.cos(ang) * dx + np.sin(ang) * dy) / s + 0.5
        lv = (-np.sin(ang) * dx + np.cos(ang) * dy) / s + 0.5
        inside = (lu >= 0) & (lu < 1) & (lv >= 0) & (lv < 1)
        iu = np.clip((lu * n).astype(np.int64), 0, n - 1)
        iv = np.clip((lv * n).astype(np.int64), 0, n - 1)
        texel = leaf[iv, iu] * inside[..., None]
        a = texel[..., 3:4]
        out[..., :3] = texel[..., :3] * a + out[..., :3] * (1 - a)
        out[..., 3:4] = a + out[..., 3:4] * (1 - a)
    # Compositing over white keeps RGB white where nothing is drawn, so filtering at mask edges does not darken.
    return out
