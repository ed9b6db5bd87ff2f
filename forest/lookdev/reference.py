"""Reference photos and masks: read, check, crop to the render's aspect, resample.

A reference is read with OpenImageIO (:func:`forest.images.read_image`, which
already refuses missing, empty, unreadable, non-finite and oversized files)
and converted to linear sRGB (8/16-bit files are sRGB-encoded, EXR/HDR are
linear).  Then:

* **aspect ratio** — if it differs from the render's ``width / height`` by more
  than 1 %, the reference is centre-cropped to that aspect (``fit="crop"``,
  the default) or squeezed to it (``fit="stretch"``), with a warning;
* **resolution** — resampled with OpenImageIO's filtered resize to exactly the
  optimiser's ``width × height`` (area filtering when shrinking, so the
  reduced-resolution loss compares box-filtered pixels on both sides);
* **content** — an all-black (or all-masked) reference is refused: nothing in
  it constrains the look;
* **size** — a reference file must have at least :func:`min_side` pixels on
  its short side: at least :data:`MIN_REFERENCE_SIDE`, and no less than the
  optimiser's short side over :data:`MAX_UPSCALE` (a smaller one would be
  blown up into a blur the fit then matches; a 1×1 "photo" fits nothing).

A **mask** is a grey image over the same frame (same crop and resampling):
white = use the pixel, black = ignore it (sky, a foreground branch, a logo);
grey values are fractional weights.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ForestError
from ..images import is_linear_file, read_image, resample, srgb_to_linear, to_rgb

MAX_REFERENCE_BYTES = 256 * 1024 * 1024
MAX_REFERENCE_PIXELS = 12000 * 12000
ASPECT_TOLERANCE = 0.01
BLACK_LEVEL = 1e-4
#: Fewest pixels on a reference file's short side.
MIN_REFERENCE_SIDE = 8
#: Largest factor a reference may be enlarged by to reach the optimiser's resolution.
MAX_UPSCALE = 4


def min_side(width: int, height: int) -> int:
    """Fewest pixels a reference needs on its short side for a fit at ``width × height``."""
    return max(MIN_REFERENCE_SIDE, math.ceil(min(width, height) / MAX_UPSCALE))


@dataclass
class Reference:
    """A reference frame ready for the loss: linear RGB and per-pixel weights at the optimiser's size."""

    path: Path | None
    rgb: np.ndarray  # (H, W, 3) float32, linear sRGB
    weight: np.ndarray  # (H, W) float32 in [0, 1]
    source_size: tuple[int, int]  # (width, height) of the file
    warnings: list[str] = field(default_factory=list)
    display_referred: bool = False  # an 8/16-bit file: sRGB-encoded, clipped at white

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the reference at the optimiser's size."""
        return self.rgb.shape[0], self.rgb.shape[1]


def _crop_box(w: int, h: int, aspect: float) -> tuple[int, int, int, int]:
    """Centred (x0, y0, x1, y1) of the largest box of ``aspect`` = width/height inside w × h."""
    if w / h > aspect:
        cw = max(1, int(round(h * aspect)))
        x0 = (w - cw) // 2
        return x0, 0, x0 + cw, h
    ch = max(1, int(round(w / aspect)))
    y0 = (h - ch) // 2
    return 0, y0, w, y0 + ch


def _fit(img: np.ndarray, width: int, height: int, fit: str) -> tuple[np.ndarray, str | None]:
    h, w = img.shape[:2]
    aspect = width / height
    note = None
    if abs((w / h) / aspect - 1.0) > ASPECT_TOLERANCE:
        if fit == "crop":
            x0, y0, x1, y1 = _crop_box(w, h, aspect)
            img = img[y0:y1, x0:x1]
            note = (
                f"aspect ratio {w}x{h} ({w / h:.3f}) differs from the render's {width}x{height} "
                f"({aspect:.3f}); centre-cropped to {x1 - x0}x{y1 - y0}"
            )
        else:
            note = (
                f"aspect ratio {w}x{h} ({w / h:.3f}) differs from the render's {width}x{height} "
                f"({aspect:.3f}); stretched to fit"
            )
    if img.shape[0] != height or img.shape[1] != width:
        img = resample(img, height, width)
    return np.ascontiguousarray(img, dtype=np.float32), note


def load_reference(
    path: str | Path | np.ndarray,
    width: int,
    height: int,
    *,
    mask: str | Path | np.ndarray | None = None,
    fit: str = "crop",
    what: str = "reference",
    max_bytes: int = MAX_REFERENCE_BYTES,
    max_pixels: int = MAX_REFERENCE_PIXELS,
) -> Reference:
    """Read a reference (a file, or an ``(H, W, 3)`` linear array) at ``width × height``.

    Raises :class:`ForestError` naming the file for an unreadable, oversized,
    too small, all-black or fully masked reference, or a mask that cannot be read.
    """
    if fit not in ("crop", "stretch"):
        raise ForestError(f"fit: must be crop or stretch, got {fit!r}")
    if isinstance(path, np.ndarray):
        src = np.asarray(path, dtype=np.float32)
        if src.ndim != 3 or src.shape[2] < 3:
            raise ForestError(f"{what}: expected an (H, W, 3) array, got shape {src.shape}")
        if not np.isfinite(src).all():
            raise ForestError(f"{what}: contains NaN or infinite values")
        rgb_full, label = src[..., :3], what
        file = None
    else:
        file = Path(path)
        label = str(file)
        img = read_image(file, what=what, max_bytes=max_bytes, max_pixels=max_pixels)
        rgb_full = to_rgb(img)
        if not is_linear_file(file):
            rgb_full = srgb_to_linear(rgb_full)
        rgb_full = np.maximum(rgb_full, 0.0)
        need = min_side(width, height)
        if min(rgb_full.shape[:2]) < need:
            raise ForestError(
                f"{label}: {what} is {rgb_full.shape[1]}x{rgb_full.shape[0]} pixels; the fit at {width}x{height} "
                f"needs at least {need} pixels on its short side"
            )
    sh, sw = rgb_full.shape[:2]
    if float(rgb_full.max(initial=0.0)) <= BLACK_LEVEL:
        raise ForestError(f"{label}: {what} is all black; nothing in it constrains the look")
    notes: list[str] = []
    rgb, note = _fit(rgb_full, width, height, fit)
    if note:
        notes.append(f"{label}: {note}")
    rgb = np.maximum(rgb, 0.0)

    weight = np.ones((height, width), dtype=np.float32)
    if mask is not None:
        if isinstance(mask, np.ndarray):
            m, mlabel = np.asarray(mask, dtype=np.float32), "mask"
        else:
            mlabel = str(mask)
            mi = read_image(mask, what="mask", max_bytes=max_bytes, max_pixels=max_pixels)
            m = mi[..., :3].mean(axis=2) if mi.shape[2] >= 3 else mi[..., 0]
        if m.ndim == 3:
            m = m[..., 0]
        if abs((m.shape[1] / m.shape[0]) / (sw / sh) - 1.0) > ASPECT_TOLERANCE:
            raise ForestError(
                f"{mlabel}: mask is {m.shape[1]}x{m.shape[0]}, its aspect ratio differs from the reference's {sw}x{sh}"
            )
        m, _ = _fit(m[..., None], width, height, fit)
        weight = np.clip(m[..., 0], 0.0, 1.0)
        if float(weight.sum()) < 1.0:
            raise ForestError(f"{mlabel}: mask excludes the whole reference")
    luminous = (rgb.max(axis=2) > BLACK_LEVEL) & (weight > 0)
    if not luminous.any():
        raise ForestError(f"{label}: {what} is black wherever the mask lets it through")
    for n in notes:
        warnings.warn(n, stacklevel=2)
    referred = file is not None and not is_linear_file(file)
    return Reference(file, rgb, weight.astype(np.float32), (sw, sh), notes, referred)


def painted_labels(path: str | Path, reference: Reference, width: int, height: int, fit: str) -> np.ndarray:
    """A painted region mask file → its labels at the fit's ``width × height``, cropped as ``reference`` was
    (:func:`forest.lookdev.regions.read_mask`, then :func:`fit_labels`); a :class:`ForestError` naming the file
    when its colours or aspect ratio do not fit."""
    from .regions import read_mask

    return fit_labels(read_mask(path), reference.source_size, width, height, fit, str(path))


def fit_labels(
    labels: np.ndarray, source_size: tuple[int, int], width: int, height: int, fit: str, label: str = "mask"
) -> np.ndarray:
    """A painted region mask (H, W) of labels → the fit's ``width × height``, cropped like the reference
    (nearest label).  A :class:`ForestError` naming the mask when its aspect ratio is not the reference's."""
    mh, mw = labels.shape
    sw, sh = source_size
    if abs((mw / mh) / (sw / sh) - 1.0) > ASPECT_TOLERANCE:
        raise ForestError(
            f"{label}: mask is {mw}x{mh}, the reference is {sw}x{sh}; paint the mask over the reference "
            "(same size or aspect ratio)"
        )
    if fit == "crop" and abs((mw / mh) / (width / height) - 1.0) > ASPECT_TOLERANCE:
        x0, y0, x1, y1 = _crop_box(mw, mh, width / height)
        labels = labels[y0:y1, x0:x1]
    mh, mw = labels.shape
    ys = np.minimum(((np.arange(height) + 0.5) * mh / height).astype(np.int64), mh - 1)
    xs = np.minimum(((np.arange(width) + 0.5) * mw / width).astype(np.int64), mw - 1)
    return labels[np.ix_(ys, xs)]
