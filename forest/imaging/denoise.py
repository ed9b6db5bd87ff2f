"""Denoising with Intel Open Image Denoise, guided by albedo and normal buffers.

OIDN's ``RT`` filter (Áfra, “Intel Open Image Denoise”, 2019–) takes the noisy
HDR colour and, optionally, first-hit **albedo** (in [0, 1]) and **normal**
(world or camera space, in [−1, 1]) images.  With them it keeps texture and
geometric edges — leaf cards, thin branches, silhouettes — that it otherwise
smears as noise.  OIDN accepts colour alone, colour + albedo, or colour + albedo
+ normal (not colour + normal: a normal buffer alone is dropped here).

The optional ``pyoidn`` package (the ``denoise`` extra) provides it; without it
:func:`denoise` returns None and the caller keeps the noisy image.

Whether a frame is denoised (:func:`denoise_rule`, ``[render] denoise``): ``true`` always (a missing
``pyoidn`` is refused before any work), ``false`` (the default) never, ``"auto"`` when ``pyoidn`` is
installed and the frame takes spp ≤ :data:`AUTO_MAX_SPP` samples per pixel; ``--preview`` always.
Measured (``bench/bench_denoise.py``, docs/rendering.md "Denoising"; 320×180, errors against a 256-spp
reference): the denoised/plain relative RMSE is 0.70–0.84 at 8 spp, 0.79–0.92 at 16, 0.91–0.97 at 32
and 0.98–1.01 at 64 on two scenes — the gain fades as the noise falls while the softened foliage stays,
so above :data:`AUTO_MAX_SPP` "auto" leaves the frame as traced.
"""

from __future__ import annotations

import numpy as np

#: ``[render] denoise = "auto"`` denoises frames of at most this many samples per pixel (the module docstring).
AUTO_MAX_SPP = 16


def oidn_available() -> bool:
    """Whether ``pyoidn`` imports."""
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return False
    return True


def denoise_rule(setting: bool | str, spp: int, *, preview: bool = False) -> tuple[bool, str]:
    """(denoise the frame?, why) for ``[render] denoise`` = ``setting`` and a frame of ``spp`` samples per pixel.

    ``preview`` or ``True``: yes; ``False``: no; ``"auto"``: yes when spp ≤ :data:`AUTO_MAX_SPP` and Open
    Image Denoise is installed, else no (silently: the reason says which).  The reason is empty for ``False``.
    """
    if preview:
        return True, "preview"
    if setting is True:
        return True, "denoise = true"
    if setting != "auto":
        return False, ""
    if int(spp) > AUTO_MAX_SPP:
        return False, f"auto: {int(spp)} spp > {AUTO_MAX_SPP}"
    if not oidn_available():
        return False, "auto: Open Image Denoise (pyoidn) not installed"
    return True, f"auto: {int(spp)} spp ≤ {AUTO_MAX_SPP}"


def _rgb(name: str, a: np.ndarray | None, shape: tuple[int, ...], lo: float, hi: float) -> np.ndarray | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=np.float32)[..., :3]
    if a.shape != shape:
        raise ValueError(f"{name} is {a.shape}, the colour is {shape}")
    return np.ascontiguousarray(np.clip(np.nan_to_num(a), lo, hi))


def denoise(
    rgb: np.ndarray,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    *,
    clean_aux: bool = False,
    quality: str = "high",
) -> np.ndarray | None:
    """Denoise linear HDR ``rgb (H, W, 3)``; None when OIDN is not installed.

    ``albedo`` and ``normal`` ``(H, W, 3)`` are passed to OIDN when given (the
    normal only together with an albedo).  ``clean_aux``: the buffers are
    noise-free (e.g. from one sample at the pixel centre with a box filter) and
    OIDN need not prefilter them; leave False for buffers averaged over the
    same noisy samples as the beauty.
    """
    try:
        import pyoidn
    except ImportError:
        return None
    colour = np.asarray(rgb, dtype=np.float32)
    if colour.ndim != 3 or colour.shape[2] < 3:
        raise ValueError(f"denoise needs (H, W, 3) colour, got {colour.shape}")
    colour = np.ascontiguousarray(np.maximum(np.nan_to_num(colour[..., :3]), 0.0))
    alb = _rgb("albedo", albedo, colour.shape, 0.0, 1.0)
    nrm = _rgb("normal", normal, colour.shape, -1.0, 1.0) if alb is not None else None
    out = pyoidn.denoise(
        colour, albedo=alb, normal=nrm, hdr=True, clean_aux=clean_aux and alb is not None, quality=quality
    )
    return np.asarray(out, dtype=np.float32)
