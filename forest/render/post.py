"""Post-processing of a rendered frame: aerial perspective and the optional denoiser."""

from __future__ import annotations

import numpy as np


def apply_haze(rgb: np.ndarray, depth: np.ndarray, hit: np.ndarray, sigma: float, colour) -> np.ndarray:
    """Aerial perspective: L·e^(−σd) + H·(1 − e^(−σd)) on pixels that hit a surface.

    The depth comes from one ray through each pixel centre, so a pixel whose
    centre sees the sky may still be partly covered by a distant silhouette
    (a ridge, a tree top).  Such sky pixels next to a hit take the largest
    depth of their 3×3 neighbours, so silhouettes against the sky are hazed
    like the ground behind them instead of leaving a dark fringe.
    """
    if sigma <= 0:
        return rgb
    from scipy.ndimage import maximum_filter

    d = np.where(hit, depth, 0.0)
    edge = ~hit & (maximum_filter(hit.astype(np.uint8), size=3) > 0)
    d = np.where(edge, maximum_filter(d, size=3), d)
    tr = np.exp(-sigma * d)[..., None]
    return (rgb * tr + np.asarray(colour, np.float32) * (1.0 - tr)).astype(np.float32)


def haze_colour(config) -> tuple[float, float, float]:
    """``[render] haze_colour``, else the constant sky's radiance, else a daylight blue."""
    hc = config.render.haze_colour
    if hc is not None:
        return tuple(hc)
    sky = config.lights.sky
    if sky is not None and sky.kind == "constant":
        return tuple(sky.radiance * c for c in sky.colour)
    return (0.5, 0.6, 0.75)


def _denoiser():
    """Intel Open Image Denoise through the optional ``pyoidn`` package, or None."""
    try:
        import pyoidn
    except ImportError:
        return None
    return pyoidn


def denoise(rgb: np.ndarray) -> np.ndarray | None:
    """Denoise a linear HDR image with OIDN's ``RT`` filter; None when OIDN is not installed."""
    oidn = _denoiser()
    if oidn is None:
        return None
    img = np.ascontiguousarray(np.maximum(rgb, 0.0), dtype=np.float32)
    return np.asarray(oidn.denoise(img, hdr=True, quality="high"), dtype=np.float32)
