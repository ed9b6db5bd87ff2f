"""forest.imaging.denoise with noisy guides: the albedo and normal are prefiltered (OIDN's recommendation) first."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from forest.imaging import denoise, oidn_available

denoise_module = importlib.import_module("forest.imaging.denoise")  # the package's `denoise` is the function

pytestmark = pytest.mark.skipif(not oidn_available(), reason="Open Image Denoise (pyoidn) is not installed")

RNG = np.random.Generator(np.random.PCG64(np.random.SeedSequence([0, 7301])))


def _spy(monkeypatch) -> list[tuple[tuple[str, ...], bool]]:
    """Record each OIDN filter run as (its image slots, cleanAux), still running it."""
    calls: list[tuple[tuple[str, ...], bool]] = []
    real = denoise_module._OIDN.run

    def run(images, *, hdr, clean_aux, quality):
        calls.append((tuple(images), clean_aux))
        return real(images, hdr=hdr, clean_aux=clean_aux, quality=quality)

    monkeypatch.setattr(denoise_module._OIDN, "run", run)
    return calls


def test_prefilter_denoises_each_guide_alone_then_the_beauty_with_clean_aux(monkeypatch):
    """``prefilter=True``: an RT filter of the albedo alone, one of the normal alone, then the beauty with them and
    ``cleanAux``; the default hands OIDN the guides as they are (``cleanAux`` off), and clean guides or none need
    no prefiltering."""
    img = RNG.random((16, 24, 3), dtype=np.float32)
    calls = _spy(monkeypatch)
    assert denoise(img, img, img * 2 - 1, prefilter=True) is not None
    assert calls == [(("albedo",), False), (("normal",), False), (("color", "albedo", "normal"), True)]
    calls.clear()
    assert denoise(img, img, prefilter=True) is not None  # albedo only
    assert calls == [(("albedo",), False), (("color", "albedo"), True)]
    calls.clear()
    assert denoise(img, img, img) is not None  # the default: the noisy guides as they are
    assert calls == [(("color", "albedo", "normal"), False)]
    calls.clear()
    assert denoise(img, img, img, clean_aux=True, prefilter=True) is not None  # clean guides: as they are
    assert calls == [(("color", "albedo", "normal"), True)]
    calls.clear()
    assert denoise(img, normal=img, prefilter=True) is not None  # a normal without albedo is dropped
    assert calls == [(("color",), False)]


def _err(img: np.ndarray | None, truth: np.ndarray) -> float:
    assert img is not None and img.shape == truth.shape
    return float(np.sqrt(np.mean((img - truth) ** 2)))


def test_prefiltering_helps_guides_whose_noise_is_their_own():
    """Guides with noise independent of the beauty's (σ = 0.05 on a 4-pixel albedo checker, 0.15 on the normal):
    prefiltered, the denoised beauty is nearer its truth than with the guides as they are; deterministic.  (Guides
    averaged over the beauty's own samples, as forest_path's are, gain nothing from it: docs/rendering.md
    "Denoising" — hence ``prefilter=False`` by default.)"""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([1, 7301])))
    h, w = 64, 64
    yy, xx = np.mgrid[0:h, 0:w]
    leaf = np.where(((xx // 4) + (yy // 4)) % 2 == 0, 0.7, 0.25)[..., None] * np.array([0.4, 0.8, 0.3])
    truth = (leaf * (1.0 + 0.4 * np.sin(xx / 11.0))[..., None]).astype(np.float32)
    noisy = (truth * rng.gamma(2.0, 0.5, size=truth.shape)).astype(np.float32)  # mean-preserving noise
    albedo = np.clip(leaf + rng.normal(0.0, 0.05, leaf.shape), 0.0, 1.0).astype(np.float32)
    normal = (np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.15, leaf.shape)).astype(np.float32)
    pre = denoise(noisy, albedo, normal, prefilter=True)
    raw = denoise(noisy, albedo, normal)
    assert _err(pre, truth) < 0.95 * _err(raw, truth) < 0.5 * _err(noisy, truth)
    assert np.array_equal(denoise(noisy, albedo, normal, prefilter=True), pre)
