"""Adaptive sampling: a per-pixel error estimate from the passes already traced, and which pixels go on.

A pixel's beauty is the Monte Carlo estimate Î = (1/n) Σᵢ Lᵢ of its n
samples' radiance.  Its luminance Yᵢ = 0.2126 Rᵢ + 0.7152 Gᵢ + 0.0722 Bᵢ
(Rec. ITU-R BT.709 weights on linear RGB) has the sample mean Ȳ = ΣY / n and
the unbiased sample variance s² = (ΣY² − n Ȳ²) / (n − 1); the standard error
of the mean is s / √n (Pharr, Jakob & Humphreys, *Physically Based Rendering*,
4th ed., 2023, ch. 2, "Monte Carlo Integration": the estimator's variance falls
as 1/n).  The pixel's *relative* error is

    e = √(s² / n) / (Ȳ + ε),      ε = :data:`EPSILON`,

so a noise threshold reads the same in the bright sky and in the shade (ε keeps
a black pixel from dividing by zero).  Only the running sums ΣL, ΣY² and n are
kept per pixel: the second moment is summed on the device beside the beauty.

After the first ``min_spp`` samples of every pixel, and after each later pass,
a pixel whose e ≤ ``noise_threshold`` stops — unless a pixel next to it (its
3×3 neighbourhood) is still noisy: the active mask is dilated by one pixel, so
a firefly or a thin twig whose first samples happened to agree is not left
behind alone.  That is the convention of Cycles' adaptive sampling ("Noise
Threshold", "Min Samples"; its convergence test is filtered over the pixel's
neighbours the same way) after Dammertz, Hanika, Keller & Lensch, "A
hierarchical automatic stopping condition for Monte Carlo global illumination",
WSCG 2009.  A stopped pixel stays stopped, so every pixel still going has the
same count, and each pass traces only the active pixels' paths.  The stopping
rule looks at the samples it averages, which biases a stopped pixel slightly
(towards estimates that look converged); at thresholds of a few per cent this
is far below the noise it leaves.
"""

from __future__ import annotations

import math

import numpy as np

from .path.frame import PassResult

#: Rec. 709 luminance weights of linear RGB.
LUMA = (0.2126, 0.7152, 0.0722)
#: ε of the relative error, in the beauty's radiance units: far below any lit pixel, so it only guards black.
EPSILON = 1.0e-3


def default_min_spp(spp: int) -> int:
    """Samples before a pixel may stop when ``[render] min_spp`` is not given: max(16, spp/8), at most spp."""
    return max(1, min(int(spp), max(16, int(spp) // 8)))


def schedule(spp: int, min_spp: int) -> list[int]:
    """Samples per pixel of each round: ``min_spp``, then rounds of ``min_spp`` (the last one the rest) up to spp.

    Each round ends with a convergence test; the rounds' sizes repeat, so their kernels compile once.
    """
    spp, step = int(spp), max(1, min(int(min_spp), int(spp)))
    rounds = [step] * (spp // step)
    if spp % step:
        rounds.append(spp % step)
    return rounds


def relative_error(sum_y: np.ndarray, sum_y2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """e = √((ΣY²/n − Ȳ²) / (n − 1)) / (Ȳ + ε) per pixel (the module docstring); +inf where n < 2."""
    n = np.asarray(n, np.float64)
    safe = np.maximum(n, 1.0)
    mean = sum_y / safe
    var_mean = np.maximum(sum_y2 / safe - mean * mean, 0.0) / np.maximum(n - 1.0, 1.0)
    err = np.sqrt(var_mean) / (np.abs(mean) + EPSILON)
    return np.where(n >= 2, err, np.inf)


def dilate(mask: np.ndarray) -> np.ndarray:
    """A (H, W) boolean mask grown by one pixel into its 8 neighbours."""
    m = np.asarray(mask, bool)
    p = np.pad(m, 1)
    out = np.zeros_like(m)
    h, w = m.shape
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            out |= p[dy : dy + h, dx : dx + w]
    return out


class Convergence:
    """Per-pixel running sums of one sub-frame's samples and the pixels still going (the module docstring)."""

    def __init__(self, height: int, width: int, threshold: float):
        self.height, self.width, self.threshold = int(height), int(width), float(threshold)
        n = self.height * self.width
        self.sum_y = np.zeros(n)
        self.sum_y2 = np.zeros(n)
        self.count = np.zeros(n)
        self.active = np.ones(n, bool)

    def add(self, p: PassResult) -> None:
        """Add one adaptive pass's sums (:meth:`~forest.render.path.PathScene.sample_pass` with ``pixels`` and
        ``luma`` = :data:`LUMA`: its ``counts`` and ``lum2``); ΣL gives ΣY, being linear."""
        assert p.counts is not None and p.lum2 is not None
        self.sum_y += p.rgb @ np.asarray(LUMA)
        self.sum_y2 += p.lum2
        self.count += p.counts

    def error(self) -> np.ndarray:
        """Each pixel's relative error e of its mean luminance so far."""
        return relative_error(self.sum_y, self.sum_y2, self.count)

    def update(self) -> np.ndarray:
        """Stop the converged pixels; the row-major indices of the pixels that go on (ascending)."""
        noisy = self.active & (self.error() > self.threshold)
        self.active &= dilate(noisy.reshape(self.height, self.width)).ravel()
        return np.flatnonzero(self.active)


def chunks(pixels: np.ndarray, spp: int, max_lanes: int) -> list[np.ndarray]:
    """``pixels`` cut into runs of at most ``max_lanes`` paths (``spp`` each), in order."""
    per = max(1, int(max_lanes) // max(1, int(spp)))
    return [pixels[i : i + per] for i in range(0, len(pixels), per)] or []


def rounds_passes(width: int, height: int, spp: int, min_spp: int, max_lanes: int) -> list[int]:
    """Samples per pixel of each pass while every pixel is still going (the most passes a render takes)."""
    pixels = int(width) * int(height)
    out: list[int] = []
    for s in schedule(spp, min_spp):
        out += [s] * math.ceil(pixels / max(1, int(max_lanes) // max(1, s)))
    return out
