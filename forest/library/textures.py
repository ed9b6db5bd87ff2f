"""Leaf textures the project draws itself: RGBA masks for alpha-tested leaf cards.

Convention for every texture of the library: the RGB channels hold a
*detail factor* (linear, mean 1 over the covered texels, so that a part's
``colour`` is its mean albedo: veins and edges darker than 1; the bark's
:func:`bark_rgb` also lighter) and alpha holds the card mask.  A renderer's leaf reflectance is therefore
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
from typing import Any

import numpy as np

from ..images import write_image

SHAPES = ("broad", "needle", "frond", "blade", "fern")
SIZE = 256


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres: ``x ∈ (-1, 1)`` across, ``t ∈ (0, 1)`` along the card."""
    c = (np.arange(n) + 0.5) / n
    t, x = np.meshgrid(c, 2.0 * c - 1.0, indexing="ij")
    return x, t


def _smooth_mask(sd: np.ndarray, n: float) -> np.ndarray:
    """Anti-aliased coverage from a signed distance (negative inside), one pixel wide edge."""
    return np.clip(0.5 - sd * n / 2.0, 0.0, 1.0)


def leaf_rgba(shape: str, n: int = SIZE) -> np.ndarray:
    """Draw a leaf card texture, ``(n, n, 4)`` float32 (RGB detail, alpha mask).

    * ``broad`` — a lens-shaped blade: half-width ``w(t) = 0.92·sin(πt)^0.8``
      (a Gielis-like superellipse), with a midrib and pinnate veins at ±40°.
    * ``needle`` — a fan of 16 needles radiating from the card's centre.
    * ``frond`` — a narrow leaflet, ``w(t) = 0.45·sin(πt)``.
    * ``blade`` — two grass blades of one tiller, unlike in length, width, lean and
      curvature (:data:`BLADES`, :func:`_blades`).
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
        alpha, detail = _blades(x, t, n)
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
    rgba[..., :3] = np.clip(detail, 0.0, 1.0)[..., None] if detail.ndim == 2 else np.clip(detail, 0.0, 1.0)
    rgba[..., 3] = np.clip(alpha, 0.0, 1.0)
    if shape != "blade":
        # A faint warm/cool shift across the leaf keeps the detail from looking flat grey.
        rgba[..., 0] *= 0.97 + 0.03 * t
        rgba[..., 2] *= 0.97 + 0.03 * (1.0 - t)
    rgba[..., :3] = unit_mean(rgba[..., :3], rgba[..., 3] >= 0.5)
    return rgba


#: The two blades of the ``blade`` card, in the card's ``x ∈ (−1, 1)``, ``t ∈ (0, 1)``: the
#: centreline ``x = base + lean·t + curve·t²`` up to the blade's length, its half-width
#: ``width`` and a per-channel tone (a second, younger blade a touch bluer-green).
BLADES: tuple[dict[str, Any], ...] = (
    {"base": -0.08, "lean": -0.34, "curve": 0.06, "length": 1.0, "width": 0.19, "tone": (1.0, 1.0, 1.0)},
    {"base": 0.10, "lean": 0.62, "curve": -0.22, "length": 0.74, "width": 0.15, "tone": (0.94, 0.98, 1.0)},
)


def _blades(x: np.ndarray, t: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Alpha ``(n, n)`` and RGB detail ``(n, n, 3)`` of the ``blade`` card: the blades of :data:`BLADES`.

    A grass blade is nearly parallel-sided and tapers to a point over its last third:
    half-width ``w(t) = width·(0.8 + 0.2·min(1, t/0.08))·√(1 − (t/L)³)`` for ``t < L``
    (narrower at the ligule).  The blades diverge from a common tiller at the
    card's foot with different leans and curvatures, so a card reads as one or two blades
    rather than a regular clump.  Detail (each blade its ``tone``): faint parallel veins
    (−4 %) and darker margins (−6 %, the blade's fold), uniform along the blade (green to the tip).
    """
    alpha = np.zeros_like(x)
    rgb = np.ones(x.shape + (3,))
    for b in BLADES:
        length = b["length"]
        centre = b["base"] + b["lean"] * t + b["curve"] * t**2
        # Horizontal distance to the centreline, corrected to the normal distance for the blade's slope.
        slope = (b["lean"] + 2.0 * b["curve"] * t) / 2.0  # dx/dt in card units (x spans 2)
        d = np.abs(x - centre) / np.sqrt(1.0 + slope**2)
        taper = np.sqrt(np.clip(1.0 - (t / length) ** 3, 0.0, 1.0))
        w = b["width"] * (0.8 + 0.2 * np.clip(t / 0.08, 0.0, 1.0)) * taper
        a = _smooth_mask(d - w, n) * (t < length)
        rel = np.clip(d / np.maximum(w, 1e-3), 0.0, 1.0)
        veins = np.cos(rel * np.pi * 3.5) ** 8
        shade = (1.0 - 0.04 * veins - 0.06 * rel**4)[..., None] * np.asarray(b["tone"])
        over = a > alpha
        rgb = np.where(over[..., None], shade, rgb)
        alpha = np.maximum(alpha, a)
    return alpha, rgb


def unit_mean(rgb: np.ndarray, mask: np.ndarray, passes: int = 4) -> np.ndarray:
    """Scale a detail factor towards mean 1 over ``mask`` while staying ≤ 1 (an 8-bit PNG's range).

    Each pass divides by the current mean over the mask and clips at 1; the
    veins and edges keep their darkening, the blade saturates at 1, and the
    mean converges from below (within 1.5 % after four passes for every shape).
    So ``part.colour`` is the leaf's mean albedo, as the presets' measured colours mean.
    """
    out = np.asarray(rgb, dtype=np.float64)
    for _ in range(passes):
        out = np.minimum(out / out[mask].mean(axis=0), 1.0)
    return out.astype(np.float32)


def coverage(shape: str) -> float:
    """Mean alpha of the shape: the share of a card that is leaf."""
    return float(leaf_rgba(shape, 128)[..., 3].mean())


def write_texture(path: str | Path, rgba: np.ndarray) -> Path:
    """Write linear straight-alpha RGBA as an sRGB PNG that keeps straight alpha (atomic, deterministic)."""
    return write_image(path, rgba, attributes={"oiio:UnassociatedAlpha": 1})


def read_texture(path: str | Path) -> np.ndarray:
    """Read a texture as linear RGB + straight alpha, float32 ``(H, W, 4)`` (alpha 1 when absent).

    PNG is sRGB-decoded; EXR (the bark's detail factor, which exceeds 1) is linear already.
    """
    from ..images import is_linear_file, read_image, srgb_to_linear

    img = read_image(path, what="texture", unassociated=True)
    c = img.shape[2]
    out = np.ones(img.shape[:2] + (4,), dtype=np.float32)
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    out[..., :3] = rgb if is_linear_file(path) else srgb_to_linear(rgb)
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


# ---------------------------------------------------------------------------
# Bark
# ---------------------------------------------------------------------------

BARK_STYLES = ("furrowed", "scaly", "ringed", "smooth", "papery")
BARK_SIZE = 256
BARK_TAG = 0xBA4C


def periodic_noise(n: int, rng: np.random.Generator, scale_u: float, scale_v: float) -> np.ndarray:
    """Tileable Gaussian noise ``(n, n)`` (rows ``v``, columns ``u``), zero mean, unit variance.

    Spectral synthesis (J. P. Lewis, "Algorithms for solid noise synthesis",
    SIGGRAPH 1989): white noise filtered in the Fourier domain by the Gaussian
    ``exp(−½((f_u·scale_u)² + (f_v·scale_v)²)·(2π)²)``, ``f`` in cycles per tile, so
    the field's correlation lengths are ``scale_u`` and ``scale_v`` (fractions of
    the tile).  The discrete Fourier transform makes it periodic: the tile repeats
    without a seam in both directions.
    """
    fv = (np.fft.fftfreq(n) * n)[:, None]
    fu = (np.fft.rfftfreq(n) * n)[None, :]  # the filter is even, so the real transform gives the same field
    h = np.exp(-0.5 * (2 * np.pi) ** 2 * ((fu * scale_u) ** 2 + (fv * scale_v) ** 2))
    x = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((n, n))) * h, s=(n, n))
    return (x - x.mean()) / max(float(x.std()), 1e-12)


def _cells(n: int, rng: np.random.Generator, count: int, aspect: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Periodic Worley cells (S. Worley, "A cellular texture basis function", SIGGRAPH 1996).

    ``count`` random sites on the torus ``[0, 1) × [0, aspect)`` (``v`` stretched
    by ``aspect``, so cells are ``aspect`` times taller than wide); returns the
    distances to the nearest and second-nearest site ``F₁, F₂`` and the nearest
    site's index, per pixel (periodic nearest neighbours: ``cKDTree(boxsize=…)``).
    """
    from scipy.spatial import cKDTree

    sites = rng.uniform(0.0, 1.0, (count, 2)) * [1.0, aspect]
    c = (np.arange(n) + 0.5) / n
    v, u = np.meshgrid(c * aspect, c, indexing="ij")
    d, i = cKDTree(sites, boxsize=[1.0, aspect]).query(np.stack([u.ravel(), v.ravel()], axis=1), k=2)
    return d[:, 0].reshape(n, n), d[:, 1].reshape(n, n), i[:, 0].reshape(n, n)


def _lenticels(n: int, rng: np.random.Generator, count: int) -> np.ndarray:
    """A factor ``(n, n)`` with ``count`` dark horizontal dashes (lenticels) on the torus: 1 − 0.85·k·e^(−r⁴),
    r the periodic distance to a dash's centre in units of its half width (u) and half height (v), k ∈ [0.5, 1]."""
    c = (np.arange(n) + 0.5) / n
    centre = rng.uniform(0.0, 1.0, (count, 2))
    half = np.stack([rng.uniform(0.02, 0.07, count), rng.uniform(0.0025, 0.0075, count)], axis=1)
    depth = rng.uniform(0.5, 1.0, count)
    out = np.ones((n, n))
    for (u0, v0), (hu, hv), k in zip(centre, half, depth):  # 160 dashes, each a separable product of two rows
        du = (c - u0 + 0.5) % 1.0 - 0.5
        dv = (c - v0 + 0.5) % 1.0 - 0.5
        r2 = (dv[:, None] / hv) ** 2 + (du[None, :] / hu) ** 2
        out *= 1.0 - 0.85 * k * np.exp(-(r2**2))
    return out


def bark_rgb(style: str, n: int = BARK_SIZE) -> np.ndarray:
    """A tileable bark *detail factor*, ``(n, n, 3)`` float32 with mean exactly 1 per channel.

    Rows run along the stem (``v``, one tile per stem circumference, see
    :func:`forest.library.lod.stem_v`), columns around it (``u``).  A part's
    albedo is ``bark_colour × detail``, so ``bark_colour`` stays the bark's mean
    albedo.  Built from :func:`periodic_noise` fields ``N(scale_u, scale_v)``:

    * ``furrowed`` — ridges and furrows running up the stem (oak, ash, most
      broadleaves): furrows where an elongated field ``N(0.02, 0.6)`` crosses
      zero, ``1 − 0.75·exp(−(N/0.4)²)``, broken by faint cross-cracks;
    * ``scaly`` — plates and scales (spruce, pine): 260 Worley cells 1.4 times taller
      than wide, each plate its own brightness and lighter towards its upper
      edge, dark cracks where ``F₂ − F₁`` is small;
    * ``ringed`` — a palm's leaf scars: a dark ring every 1/18 of a tile, wavy by
      ``0.15·N``, over fine fibres running up the stem;
    * ``smooth`` — a thin mottled bark (beech, young stems): low-contrast noise;
    * ``papery`` — a birch's white bark: fine peeling bands around the stem
      ``N(0.05, 0.004)``, 160 dark lenticels (dashes 4–14 % of a circumference
      wide and 0.5–1.5 % tall, darkened by up to 85 % with a soft quartic edge)
      and dark blotches where a field ``N(0.05, 0.08)`` exceeds 1.3 σ (branch
      scars and the dark bark between the white).

    Every style adds fine grain and a faint low-frequency hue shift (lichen and
    weathering).  The style's stream is fixed, so every species of one style
    shares its bark.  Species write it as a linear half-float EXR (``bark.exr``):
    a detail factor with mean 1 exceeds 1 where the bark is light, which an
    8-bit PNG cannot hold.
    """
    if style not in BARK_STYLES:
        raise ValueError(f"unknown bark style {style!r}")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([BARK_TAG, BARK_STYLES.index(style)])))
    c = (np.arange(n) + 0.5) / n
    v = c[:, None] * np.ones((1, n))
    grain = periodic_noise(n, rng, 0.004, 0.012)
    if style == "furrowed":
        furrow = np.exp(-((periodic_noise(n, rng, 0.02, 0.6) / 0.4) ** 2))
        crack = np.exp(-((periodic_noise(n, rng, 0.15, 0.015) / 0.15) ** 2)) * (1.0 - furrow)
        relief = periodic_noise(n, rng, 0.01, 0.06)
        d = (1.0 - 0.75 * furrow) * (1.0 - 0.3 * crack) * (1.0 + 0.12 * relief)
    elif style == "scaly":
        f1, f2, idx = _cells(n, rng, 260, 1.4)
        bright = rng.uniform(0.7, 1.25, 260)[idx]
        edge = f2 - f1
        crack = np.exp(-((edge / 0.008) ** 2))
        lift = np.clip(1.0 - f1 / 0.07, 0.0, 1.0)
        d = bright * (0.85 + 0.2 * lift) * (1.0 - 0.75 * crack)
    elif style == "ringed":
        phase = v * 18.0 + 0.15 * periodic_noise(n, rng, 0.15, 0.5)
        f = phase - np.floor(phase)
        scar = np.exp(-(((f - 0.5) / 0.11) ** 2))
        swell = 0.85 + 0.3 * np.sin(np.pi * f) ** 2
        fibre = periodic_noise(n, rng, 0.004, 0.05)
        d = swell * (1.0 - 0.6 * scar) * (1.0 + 0.12 * fibre)
    elif style == "papery":
        d = _lenticels(n, rng, 160)
        blotch = np.clip((periodic_noise(n, rng, 0.05, 0.08) - 1.3) / 0.35, 0.0, 1.0)
        d = d * (1.0 - 0.85 * blotch) * (1.0 + 0.07 * periodic_noise(n, rng, 0.05, 0.004))
    else:  # smooth
        d = 1.0 + 0.12 * periodic_noise(n, rng, 0.08, 0.08) + 0.05 * periodic_noise(n, rng, 0.02, 0.006)
    d = np.clip(d * (1.0 + 0.06 * grain), 0.05, None)
    tint = np.stack([1.0 + s * periodic_noise(n, rng, 0.15, 0.2) for s in (0.025, 0.02, 0.03)], axis=-1)
    rgb = d[..., None] * tint
    rgb /= rgb.reshape(-1, 3).mean(axis=0)
    return rgb.astype(np.float32)


# ---------------------------------------------------------------------------
# Ground
# ---------------------------------------------------------------------------

GROUND_SIZE = 256
GROUND_TAG = 0x6E0D


def ground_detail_rgb(n: int = GROUND_SIZE) -> np.ndarray:
    """A tileable ground *detail factor*, ``(n, n, 3)`` float32 with mean exactly 1 per channel.

    The terrain's albedo is ``material colour × detail`` (:class:`forest.ground.TerrainAlbedo`),
    so the materials keep their measured mean albedo and the detail adds what a
    few metres of ground show: soft lighter and darker patches
    (:func:`periodic_noise` at about 1/20 and 1/70 of the tile: nothing large
    enough to show the repeat), pebbles and clods (4 in 10 of 400 small Worley
    cells, S. Worley 1996, each lighter or darker towards its centre with a
    dark rim), grain (1/250 of the tile), and a faint hue shift between warmer and cooler patches.  Contrast
    is about ±20 % — enough to read as
    ground at a few metres, averaging out to the material's colour farther
    away.  The stream is fixed, so every scene shares the texture.
    """
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([GROUND_TAG, n])))
    # Soft, irregular patches of lighter and darker ground at three scales …
    patches = 0.10 * periodic_noise(n, rng, 0.045, 0.045) + 0.08 * periodic_noise(n, rng, 0.015, 0.015)
    # … scattered pebbles and clods (small Worley cells, most of them faint) …
    f1, f2, idx = _cells(n, rng, 400, 1.0)
    pebble = rng.uniform(-1.0, 1.0, 400)[idx] * (rng.random(400) < 0.4)[idx]
    rim = np.exp(-(((f2 - f1) / 0.005) ** 2))
    stones = 0.35 * pebble * np.clip(1.0 - f1 / 0.025, 0.0, 1.0) ** 0.5 - 0.08 * rim * (pebble != 0)
    # … and grain.
    grain = 0.08 * periodic_noise(n, rng, 0.004, 0.004)
    d = np.clip(1.0 + patches + stones + grain, 0.3, None)
    hue = periodic_noise(n, rng, 0.04, 0.04)
    rgb = d[..., None] * np.stack([1.0 + 0.03 * hue, np.ones_like(hue), 1.0 - 0.04 * hue], axis=-1)
    rgb /= rgb.reshape(-1, 3).mean(axis=0)
    return rgb.astype(np.float32)
