"""Calibrating the proxy against the production render it stands in for.

The proxy bakes the forest at the finest levels of detail its triangle budget
allows (:mod:`.forest_proxy`); when the budget demotes trees the production
render would draw finer, coarser crowns look darker and bluer (less leaf
inter-reflection), and a fit would fold that difference into the look.  On
the benchmark's unaligned scene (370 trees in view, 2 M-triangle budget) the
proxy's ground and foliage came out 14 %, 4 % and 27 % darker in R, G, B than
the ``scalar_rgb`` render of the same state; with a 24 M-triangle budget the
two agree within 0.8 %, but that proxy takes 47 s and 7 GB to build.

Instead, a small production render of the starting look, at the
optimiser's resolution, measures a per-channel gain

    k_c = Σ_{p ∉ sky} P_pc / Σ_{p ∉ sky} X_pc

(P production, X proxy, the sums over pixels whose centre ray hits the
scene), and the proxy multiplies every such pixel by k from then on
(:meth:`forest.lookdev.proxy.Proxy.set_gain`), gradients included.  A global
gain is what a global fit (``statistics`` mode's tint) can use; it is the
default there and optional in ``aligned`` mode (``[lookdev] calibrate``),
where a reference made by the proxy itself must not be calibrated.

Measured on the benchmark's unaligned photo: the fitted tint's error to the
hidden one fell from 4.9 to 2.9 CIEDE2000.  The gain is a first-order
model: the difference depends on the look (measuring it again at the fitted
look and refitting made the tint worse, 2.3 → 3.5 on the same forest), and
part of what is left is that look-dependent difference.
"""

from __future__ import annotations

import numpy as np

CALIBRATION_SPP = 64
GAIN_LIMITS = (0.25, 4.0)


def production_image(scene, state, *, width: int, height: int, spp: int = CALIBRATION_SPP) -> np.ndarray:
    """The ``scalar_rgb`` production render of ``scene`` with ``state``'s lights: (H, W, 3) linear, no files."""
    from ..render.render import render_image

    lit = scene.with_config(scene.config.with_overrides(state.config_overrides()))
    return render_image(lit, width=width, height=height, spp=spp)


def channel_gain(production: np.ndarray, proxy_image: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """k_c (module docstring) over the ``hit`` pixels, clamped to :data:`GAIN_LIMITS`; ones if nothing is hit."""
    if not hit.any():
        return np.ones(3)
    p = np.asarray(production, np.float64)[hit].sum(axis=0)
    x = np.asarray(proxy_image, np.float64)[hit].sum(axis=0)
    k = np.where(x > 1e-12, p / np.maximum(x, 1e-12), 1.0)
    return np.clip(k, *GAIN_LIMITS)
