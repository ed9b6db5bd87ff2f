"""What is where: sky, canopy and ground in the render and in the photo, and painted masks.

**In the render** the regions come from forest's own layers (one ray per pixel
centre, :attr:`.renders.FitRenderer.layers`): *sky* where nothing is hit,
*canopy* where a tree is hit (any species, leaves and bark), *ground* where
the terrain is hit.

**In the photo** (statistics mode, unless ``--mask`` paints them) an automatic
segmentation assigns the same three regions:

1. *sky*: pixels that are bright (above the Otsu threshold of ln Y over the
   frame; Otsu 1979), smooth (local standard deviation of ln Y over 5×5 below
   0.25) and not green (excess green 2g − r − b below 0.1 of the brightness;
   Woebbecke et al. 1995), in the connected parts that touch the top edge;
   1b. and, where the render shows sky, the not-green pixels above the photo's
   *skyline*: in each such column, the row near the render's skyline (within
   15 % of the height) where the frame darkens markedly from the rows above to the
   rows below — a textured sky (a sunset's clouds) fails the smoothness test of
   step 1 but is still brighter than the land under it;
2. *ground* and *canopy* among the rest, row by row: the cameras roughly
   match, so a row of the photo gets the share of ground its row in the render
   has (among non-sky pixels, smoothed over ±5 % of the height), and the
   pixels given to the ground are the row's most ground-like.  What is
   ground-like is learnt from the render of the same view: five features per
   pixel — ln Y, excess green, ln(r/g), ln(b/g) and the 3×3 spread of ln Y —
   each standardised over its own image's non-sky pixels, and Fisher's linear
   discriminant (Fisher 1936) between the render's ground and canopy pixels
   gives the direction along which the photo's pixels are ranked.  Standardised
   features carry the render's *relative* cues to the photo whatever the start
   look's colours: ground brighter than canopy on a meadow, yellower on an
   autumn hillside, smoother under a canopy.  Without a render image (or with
   too few pixels of either) the least green are the ground.

Its limits: it needs the camera to frame the scene roughly as the photo does
(the ground share per row comes from the render); it cannot tell a green
meadow from a canopy or an orange autumn canopy from bare soil by colour, only
by position; a bright, smooth, not-green object touching the top edge (a
white wall, a cloudless snowfield) passes for sky; fog or an overcast sky whose
brightness is that of the ground may be missed.  A painted mask overrides it.

**Masks** (``--mask``): an image of the reference's aspect ratio painted in
:data:`PALETTE` colours — sky blue ``#0000ff``, canopy green ``#00ff00``,
ground red ``#ff0000``, black ``#000000`` ignored, white ``#ffffff`` left to the
automatic segmentation.  A pixel takes the palette colour it is within
:data:`MASK_TOLERANCE` (8-bit, per channel) of; up to :data:`MASK_STRAY`
of the pixels may be off the palette (antialiased edges) and are ignored.

**Lit and shadowed.** Within canopy and ground, the render's sunlit fraction f
(pixels whose direct sun is at least half their radiance) splits each region
of both images by lightness: its brightest f is *lit*, the rest *shadowed* —
the same rule on both sides, since a photo's shadows cannot be told from its
dark albedos by colour alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ForestError

SKY, CANOPY, GROUND = 0, 1, 2
IGNORE, AUTO = -1, -2
NAMES = {SKY: "sky", CANOPY: "canopy", GROUND: "ground"}
PALETTE = {
    SKY: (0, 0, 255),
    CANOPY: (0, 255, 0),
    GROUND: (255, 0, 0),
    IGNORE: (0, 0, 0),
    AUTO: (255, 255, 255),
}
MASK_TOLERANCE = 48
MASK_STRAY = 0.02
#: Smallest share of the pixels a region needs in both images to be compared.
MIN_REGION = 0.02
#: The photo's skyline is searched within this share of the height of the render's.
SKYLINE_WINDOW = 0.15
#: Rows (share of the height) averaged above and below a candidate skyline.
SKYLINE_BAND = 0.08
#: Least drop of mean ln Y across the skyline (ln units: the land at most ~2/3 as bright as the sky).
SKYLINE_DROP = 0.4


def render_labels(layers: dict[str, np.ndarray]) -> np.ndarray:
    """(H, W) SKY / CANOPY / GROUND from the render's layers."""
    lab = np.full(layers["depth"].shape, SKY, np.int64)
    lab[layers["hit"] & (layers["id"] >= 0)] = CANOPY
    lab[layers["hit"] & (layers["id"] < 0)] = GROUND
    return lab


def read_mask(path: str | Path, what: str = "mask") -> np.ndarray:
    """A painted mask file → (H, W) labels (SKY, CANOPY, GROUND, IGNORE, AUTO); a :class:`ForestError`
    naming the file when its colours do not fit the palette."""
    from ..images import read_image

    img = read_image(path, what=what)
    rgb = img[..., :3] if img.shape[2] >= 3 else np.repeat(img[..., :1], 3, axis=2)
    return mask_labels(np.round(np.clip(rgb, 0, 1) * 255.0), str(path))


def mask_labels(rgb8: np.ndarray, label: str = "mask") -> np.ndarray:
    """8-bit RGB (H, W, 3) → labels by the nearest palette colour within the tolerance."""
    keys = list(PALETTE)
    pal = np.array([PALETTE[k] for k in keys], np.float64)
    dist = np.abs(rgb8[..., None, :].astype(np.float64) - pal).max(axis=-1)  # (H, W, K)
    best = dist.argmin(axis=-1)
    ok = dist.min(axis=-1) <= MASK_TOLERANCE
    labels = np.asarray(keys)[best]
    stray = 1.0 - float(ok.mean())
    if stray > MASK_STRAY:
        ys, xs = np.nonzero(~ok)
        c = rgb8[ys[0], xs[0]].astype(int)
        raise ForestError(
            f"{label}: {100 * stray:.1f} % of the mask's pixels are none of its colours (e.g. #{c[0]:02x}{c[1]:02x}"
            f"{c[2]:02x} at x={xs[0]}, y={ys[0]}); paint sky #0000ff, canopy #00ff00, ground #ff0000, "
            "ignored #000000, automatic #ffffff"
        )
    return np.where(ok, labels, IGNORE).astype(np.int64)


def _otsu(x: np.ndarray) -> float:
    """Otsu's (1979) threshold of a 1-D sample (256 bins)."""
    hist, edges = np.histogram(x, bins=256)
    p = hist.astype(np.float64) / max(hist.sum(), 1)
    mids = 0.5 * (edges[1:] + edges[:-1])
    w0 = np.cumsum(p)
    m0 = np.cumsum(p * mids)
    mt = m0[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (mt * w0 - m0) ** 2 / (w0 * (1.0 - w0))
    between[~np.isfinite(between)] = 0.0
    return float(mids[int(np.argmax(between))])


#: Features of :func:`ground_score`: ln Y, excess green, ln(r/g), ln(b/g), the 3×3 spread of ln Y.
N_FEATURES = 5


def pixel_features(rgb: np.ndarray) -> np.ndarray:
    """(H, W, :data:`N_FEATURES`) features of a linear image for telling ground from canopy."""

    c = np.maximum(np.asarray(rgb, np.float64), 1e-5)
    ly = np.log(np.maximum(c @ np.array([0.2126, 0.7152, 0.0722]), 1e-5))
    exg = (2 * c[..., 1] - c[..., 0] - c[..., 2]) / c.sum(axis=2)
    spread = local_spread(ly, 3)
    return np.stack([ly, exg, np.log(c[..., 0] / c[..., 1]), np.log(c[..., 2] / c[..., 1]), spread], axis=-1)


def local_spread(x: np.ndarray, size: int) -> np.ndarray:
    """The standard deviation of ``x`` over each size×size window (edges clamped)."""
    from scipy.ndimage import uniform_filter

    mean = uniform_filter(x, size, mode="nearest")
    return np.sqrt(np.maximum(uniform_filter(x * x, size, mode="nearest") - mean * mean, 0.0))


def _standardised(f: np.ndarray, mask: np.ndarray) -> np.ndarray:
    mu = f[mask].mean(axis=0)
    sd = f[mask].std(axis=0) + 1e-6
    return (f - mu) / sd


def ground_score(rgb: np.ndarray, sky: np.ndarray, render: np.ndarray, render_rgb: np.ndarray | None) -> np.ndarray:
    """(H, W): how ground-like each photo pixel is (higher: more), by Fisher's discriminant between the render's
    ground and canopy pixels on standardised features (module docstring, step 2); minus excess green without a
    render image."""
    fp = pixel_features(rgb)
    fallback = -fp[..., 1]
    if render_rgb is None or not (~sky).any():
        return fallback
    zp = _standardised(fp, ~sky)
    zr = _standardised(pixel_features(render_rgb), render != SKY)
    a, b = zr[render == GROUND], zr[render == CANOPY]
    if len(a) < 5 or len(b) < 5:
        return fallback
    pooled = np.concatenate([a - a.mean(axis=0), b - b.mean(axis=0)])
    cov = pooled.T @ pooled / max(len(pooled) - 1, 1) + 1e-3 * np.eye(N_FEATURES)
    return zp @ np.linalg.solve(cov, a.mean(axis=0) - b.mean(axis=0))


def segment_photo(
    rgb: np.ndarray, render: np.ndarray, weight: np.ndarray | None = None, render_rgb: np.ndarray | None = None
) -> np.ndarray:
    """Automatic SKY / CANOPY / GROUND labels of a linear photo (H, W, 3), guided by the render's labels
    ``render`` (H, W) of the same view and, when given, its image ``render_rgb`` (see the module docstring)."""
    from scipy.ndimage import label as components
    from scipy.ndimage import uniform_filter

    h, w = rgb.shape[:2]
    y = np.maximum(rgb @ np.array([0.2126, 0.7152, 0.0722]), 1e-5)
    ly = np.log(y)
    std = local_spread(ly, 5)
    s = rgb.sum(axis=2) + 1e-6
    exg = (2 * rgb[..., 1] - rgb[..., 0] - rgb[..., 2]) / s
    bright = ly > _otsu(ly.ravel())
    cand = bright & (std < 0.25) & (exg < 0.1)
    comp, _ = components(cand)
    top = set(np.unique(comp[0][comp[0] > 0]).tolist())
    sky = np.isin(comp, list(top)) if top else np.zeros((h, w), bool)
    sky |= skyline_sky(ly, exg, render)
    labels = np.full((h, w), CANOPY, np.int64)
    labels[sky] = SKY
    # Ground share per row, from the render (non-sky pixels), smoothed over ±5 % of the height.
    rsolid = render != SKY
    share = np.where(rsolid.sum(1) > 0, (render == GROUND).sum(1) / np.maximum(rsolid.sum(1), 1), np.nan)
    rows = np.arange(h)
    known = np.isfinite(share)
    share = np.interp(rows, rows[known], share[known]) if known.any() else np.zeros(h)
    k = max(1, int(round(0.05 * h)))
    share = uniform_filter(share, 2 * k + 1, mode="nearest")
    score = ground_score(rgb, sky, render, render_rgb)
    for r in range(h):
        free = np.flatnonzero(~sky[r])
        n_ground = int(round(share[r] * len(free)))
        if n_ground <= 0 or not len(free):
            continue
        order = free[np.argsort(-score[r, free], kind="stable")]
        labels[r, order[:n_ground]] = GROUND
    if weight is not None:
        labels[weight <= 0] = IGNORE
    return labels


def skyline_sky(ly: np.ndarray, exg: np.ndarray, render: np.ndarray) -> np.ndarray:
    """Sky above the photo's skyline, found near the render's (see the module docstring, step 1b).

    ``ly`` (H, W) ln luminance, ``exg`` excess green, ``render`` the render's labels.  ln Y is first averaged
    over ±5 % of the width (a skyline is smooth across columns; a cloud's edge is not).  In each column where
    the render shows sky down to row r, the skyline is the first row b within ±:data:`SKYLINE_WINDOW` of r
    where mean ln Y drops by at least :data:`SKYLINE_DROP` from the :data:`SKYLINE_BAND` rows above it to
    those below it, moved down to where that drop peaks; a column without such a row keeps no sky from this
    step.  The rows found are smoothed by a median over ±5 % of the width.  Sky: the not-green pixels above
    the skyline.
    """
    from scipy.ndimage import median_filter, uniform_filter

    h, w = ly.shape
    none = np.zeros((h, w), bool)
    sky_rows = np.cumprod(render == SKY, axis=0).sum(axis=0)  # render sky rows from the top, per column
    cols = np.flatnonzero(sky_rows > 0)
    if not len(cols) or h < 6:
        return none
    size = max(1, int(round(0.05 * w))) * 2 + 1
    ly = uniform_filter(ly, size=(1, size), mode="nearest")
    band = max(2, int(round(SKYLINE_BAND * h)))
    win = max(2, int(round(SKYLINE_WINDOW * h)))
    csum = np.vstack([np.zeros((1, w)), np.cumsum(ly, axis=0)])
    rows = np.arange(1, h)
    lo_a = np.maximum(rows - band, 0)
    hi_b = np.minimum(rows + band, h)
    above = (csum[rows] - csum[lo_a]) / (rows - lo_a)[:, None]
    below = (csum[hi_b] - csum[rows]) / (hi_b - rows)[:, None]
    drop = above - below  # (H − 1, W): split before row rows[i]
    b = np.full(w, -1)
    for c in cols:
        r = int(sky_rows[c])
        lo, hi = max(1, r - win), min(h - 1, r + win)
        d = drop[lo - 1 : hi, c]
        ok = np.flatnonzero(d >= SKYLINE_DROP)
        if len(ok):
            k = int(ok[0])
            while k + 1 < len(d) and d[k + 1] > d[k]:  # up to the edge itself: the drop's first peak
                k += 1
            b[c] = lo + k
    found = b > 0
    if not found.any():
        return none
    filled = np.where(found, b, np.interp(np.arange(w), np.flatnonzero(found), b[found]))
    smooth = median_filter(filled.astype(np.float64), size=size, mode="nearest")
    return (np.arange(h)[:, None] < np.where(found, smooth, 0)[None, :]) & (exg < 0.1)


def photo_labels(
    rgb: np.ndarray, render: np.ndarray, painted: np.ndarray | None, render_rgb: np.ndarray | None = None
) -> np.ndarray:
    """The photo's labels: the painted mask where it names a region, the automatic segmentation elsewhere."""
    auto = segment_photo(rgb, render, render_rgb=render_rgb)
    if painted is None:
        return auto
    return np.where(painted == AUTO, auto, painted)


@dataclass(frozen=True)
class Region:
    """A compared region: its name and its pixels in the render and in the photo (flat boolean masks)."""

    name: str
    render: np.ndarray
    photo: np.ndarray


def lightness(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of each colour of ``rgb`` (..., 3), flattened to (N,)."""
    return np.asarray(rgb, np.float64).reshape(-1, 3) @ np.array([0.2126, 0.7152, 0.0722])


def split_lit(mask: np.ndarray, image: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(lit, shadowed): the brightest ``fraction`` of ``mask``'s pixels of ``image`` and the rest."""
    idx = np.flatnonzero(mask)
    lit = np.zeros_like(mask)
    if not len(idx):
        return lit, mask.copy()
    y = lightness(image)[idx]
    n = int(round(np.clip(fraction, 0.0, 1.0) * len(idx)))
    order = idx[np.argsort(-y, kind="stable")]
    lit[order[:n]] = True
    return lit, mask & ~lit


def regions(
    render_lab: np.ndarray,
    photo_lab: np.ndarray,
    *,
    sky_up: np.ndarray,
    sun_lit: np.ndarray | None,
    render_img: np.ndarray,
    photo_img: np.ndarray,
) -> list[Region]:
    """The regions both images show: sky (high / low halves by the ray's elevation), canopy and ground
    (each whole, and lit / shadowed when there is a sun).  ``sky_up`` is each pixel's ray elevation
    (sin), ``sun_lit`` the render's sunlit pixels."""
    n = render_lab.size
    r, p = render_lab.ravel(), photo_lab.ravel()
    out: list[Region] = []

    def add(name: str, rm: np.ndarray, pm: np.ndarray) -> None:
        if rm.sum() >= MIN_REGION * n and pm.sum() >= MIN_REGION * n:
            out.append(Region(name, rm, pm))

    up = sky_up.ravel()
    rs, ps = r == SKY, p == SKY
    add("sky", rs, ps)
    if rs.sum() and ps.sum():
        cut = float(np.median(up[ps]))
        add("sky high", rs & (up >= cut), ps & (up >= cut))
        add("sky low", rs & (up < cut), ps & (up < cut))
    for lab in (CANOPY, GROUND):
        rm, pm = r == lab, p == lab
        name = NAMES[lab]
        add(name, rm, pm)
        if sun_lit is not None and rm.sum() and pm.sum():
            f = float(sun_lit.ravel()[rm].mean())
            if 0.05 < f < 0.95:
                rl, rd = split_lit(rm, render_img, f)
                pl, pd = split_lit(pm, photo_img, f)
                add(f"{name} lit", rl, pl)
                add(f"{name} shadowed", rd, pd)
    return out


def region_means(image: np.ndarray, masks: list[np.ndarray]) -> np.ndarray:
    """(K, 3) mean linear colour of each flat mask."""
    flat = np.asarray(image, np.float64).reshape(-1, 3)
    return np.stack([flat[m].mean(axis=0) for m in masks]) if masks else np.zeros((0, 3))


#: Percentiles of L*, a*, b* a region's statistics give (beyond its mean colour).
PERCENTILES = (10, 50, 90)


def region_statistics(image: np.ndarray, mask: np.ndarray) -> dict[str, list[float]]:
    """The spread of a region's colours: the :data:`PERCENTILES` of CIELAB L*, a*, b* of ``image``'s (linear,
    (H, W, 3)) pixels in the flat ``mask`` — what a mean hides (a canopy of one flat colour and one of dark
    gaps and bright crowns can share a mean)."""
    from .colour import rgb_to_lab

    px = np.asarray(image, np.float64).reshape(-1, 3)[np.asarray(mask, bool).ravel()]
    if not len(px):
        return {}
    lab = rgb_to_lab(np.maximum(px, 0.0))
    return {k: [float(v) for v in np.percentile(lab[:, i], PERCENTILES)] for i, k in enumerate(("L*", "a*", "b*"))}


def lit_contrast(image: np.ndarray, mask: np.ndarray, fraction: float) -> float | None:
    """Mean luminance of a region's lit part over its shadowed part (:func:`split_lit` with the render's sunlit
    ``fraction``), or None when either part is empty."""
    lit, dark = split_lit(np.asarray(mask, bool).ravel(), image, fraction)
    if not lit.any() or not dark.any():
        return None
    y = lightness(image)
    return float(y[lit].mean() / max(y[dark].mean(), 1e-12))


def label_iou(labels: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Intersection over union of each region (sky, canopy, ground) between ``labels`` and painted ``truth``
    labels of the same shape, over the pixels ``truth`` names (ignored and automatic pixels left out); a region
    neither names is left out."""
    keep = truth >= 0
    out = {}
    for lab, name in NAMES.items():
        a, b = (labels == lab) & keep, (truth == lab) & keep
        union = int((a | b).sum())
        if union:
            out[name] = float((a & b).sum() / union)
    return out
