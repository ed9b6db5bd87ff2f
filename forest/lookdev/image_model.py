"""The photograph as a function of the render: exposure, white balance, clipping (and a haze step).

Aerial perspective is part of the production render (the forest path tracer's
exponential height fog, :mod:`forest.render.path.haze`), so a render R at a
look already carries that look's haze.  What a camera records of it is

    P = 2^EV · W ⊙ R          (exposure, von Kries white balance)
    Q = min(P, 1)             (a display-referred file clips)

with W the white-balance gains (unit luminance).  Because the path tracer is
linear in its light scales and the haze radiance, and renders each colour
channel on its own, folding 2^EV·W into the lights and the haze colour renders
exactly P — which is how a fit is written back (:mod:`.report`).  8- and
16-bit references are display-referred, so Q is compared with them; a float
(EXR/HDR) reference is not clipped.

**A haze step in the surrogate.**  Between renders the Gauss–Newton surrogate
(:mod:`.solve`) predicts a change Δσ of the ground extinction from the render at
σ_k: each pixel's camera segment has optical depth τ = σ·D with D its *optical
length* (:func:`optical_length`: the height-fog integral of the renderer over the
segment to the first hit, or to the haze's sky distance for the sky), so

    R(σ) ≈ R(σ_k) · e^(−Δσ D) + A · (1 − e^(−Δσ D))

with A the haze radiance (Koschmieder 1924; the single-scattering form of
:mod:`forest.render.path.haze` without its sun lobe).  Only the step uses it:
every iterate is judged on a production render at its own σ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def optical_length(
    origin_y: float, directions: np.ndarray, length: np.ndarray, *, ground: float, height: float
) -> np.ndarray:
    """D = τ/σ₀ of the segments from a camera at height ``origin_y`` along unit ``directions`` (H, W, 3) for
    ``length`` (H, W) metres through the fog σ(y) = σ₀·exp(−(y − ground)/height):
    D = e^(−(o_y − y₀)/H) · ℓ · φ(ℓ d_y / H), φ(x) = (1 − e^(−x))/x (see :mod:`forest.render.path.haze`)."""
    from ..render.path.haze import phi_np

    ell = np.asarray(length, np.float64)
    dy = np.asarray(directions, np.float64)[..., 1]
    return float(np.exp(-(float(origin_y) - float(ground)) / float(height))) * ell * phi_np(ell * dy / float(height))


@dataclass
class ImageModel:
    """Optical lengths and clipping of one view; :meth:`apply` maps a render to the photo it predicts."""

    optical: np.ndarray  # (H, W) optical length D of each pixel's camera segment (0 without a haze)
    clip: bool

    def transmittance(self, d_sigma: float) -> np.ndarray:
        """e^(−Δσ D) per pixel, (H, W, 1)."""
        return np.exp(-float(d_sigma) * self.optical)[..., None]

    def apply(
        self, render: np.ndarray, *, gain: np.ndarray, d_sigma: float = 0.0, airlight: np.ndarray | None = None
    ) -> np.ndarray:
        """Q of the module docstring; ``d_sigma`` ≠ 0 moves the haze by Δσ from the render's (a surrogate)."""
        p = np.asarray(render, np.float64)
        if d_sigma != 0.0:
            t = self.transmittance(d_sigma)
            a = np.zeros(3) if airlight is None else np.asarray(airlight, np.float64)
            p = p * t + a * (1.0 - t)
        p = p * np.asarray(gain, np.float64)
        return np.minimum(p, 1.0) if self.clip else p
