"""The photograph as a function of the render: aerial perspective, exposure, white balance, clipping.

For a linear render R (the forest path tracer's radiance), the model of what
a camera records is

    H = R · t + A · (1 − t),        t = e^(−σ d)       (Koschmieder 1924)
    P = 2^EV · W ⊙ H                                    (exposure, von Kries white balance)
    Q = min(P, 1)                                       (a display-referred file clips)

with d each pixel's depth, σ the haze extinction, A the airlight radiance and
W the white-balance gains (unit luminance).  The haze is exactly the
production renderer's post-process (:func:`forest.render.post.apply_haze`):
the same depth from one ray per pixel centre, and sky pixels next to a hit
take their neighbours' largest depth.  Because the path tracer is linear in
its light scales and renders each colour channel on its own, folding 2^EV·W
into the lights and A renders exactly P — which is how a fit is written back
(:mod:`.report`).  8- and 16-bit references are display-referred, so Q is
compared with them; a float (EXR/HDR) reference is not clipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def haze_depth(depth: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """The depth the production haze uses per pixel: the hit's, or the largest 3×3 neighbour's at a sky pixel
    next to a hit, else 0 (:func:`forest.render.post.apply_haze`)."""
    from scipy.ndimage import maximum_filter

    d = np.where(hit, depth, 0.0)
    edge = ~hit & (maximum_filter(hit.astype(np.uint8), size=3) > 0)
    return np.where(edge, maximum_filter(d, size=3), d)


@dataclass
class ImageModel:
    """Depth and clipping of one view; :meth:`apply` maps a render to the photo it predicts."""

    depth: np.ndarray  # (H, W) haze depth (:func:`haze_depth`), 0 where the sky is seen
    clip: bool

    def transmittance(self, sigma: float) -> np.ndarray:
        return np.exp(-max(float(sigma), 0.0) * self.depth)[..., None]

    def apply(self, render: np.ndarray, *, sigma: float, airlight: np.ndarray, gain: np.ndarray) -> np.ndarray:
        t = self.transmittance(sigma)
        p = (render * t + np.asarray(airlight, np.float64) * (1.0 - t)) * np.asarray(gain, np.float64)
        return np.minimum(p, 1.0) if self.clip else p
