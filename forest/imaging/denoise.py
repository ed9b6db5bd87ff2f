"""Denoising with Intel Open Image Denoise, guided by albedo and normal buffers.

OIDN's ``RT`` filter (Áfra, “Intel Open Image Denoise”, 2019–) takes the noisy
HDR colour and, optionally, first-hit **albedo** (in [0, 1]) and **normal**
(world or camera space, in [−1, 1]) images.  With them it keeps texture and
geometric edges — leaf cards, thin branches, silhouettes — that it otherwise
smears as noise.  OIDN accepts colour alone, colour + albedo, or colour + albedo
+ normal (not colour + normal: a normal buffer alone is dropped here).

forest_path's guides are averages over the beauty's own samples (noisy where a
pixel is partly covered by stochastic leaf-card alpha).  OIDN takes such guides
as they are (``cleanAux`` off, the default here), or, as its documentation
recommends for the highest quality, **prefiltered**: each guide denoised first by
an ``RT`` filter of that image alone, then the beauty with the cleaned guides and
``cleanAux`` on (:func:`denoise` with ``prefilter=True``, :func:`prefilter_guide`).
Measured on forest's scenes, prefiltering is *worse* and about 7× the denoiser's
time: the albedo guide is nearly clean already (on the demo, RMSE 0.0067 against
the 256-spp guide at 8 spp; 0.0065 prefiltered), and the prefilter takes
leaf-scale detail out of it with the noise (from 16 spp on the prefiltered guide
is farther from the converged one: 0.0021 → 0.0031 at 64 spp), so the beauty
filter, trusting it, softens the canopy more.
Prefiltering pays for guides with noise of their own (tests/test_denoise_guides.py).

The optional ``pyoidn`` package (the ``denoise`` extra) provides it; without it
:func:`denoise` returns None and the caller keeps the noisy image.

Whether a frame is denoised (:func:`denoise_rule`, ``[render] denoise``): ``true`` always (a missing
``pyoidn`` is refused before any work), ``false`` (the default) never, ``"auto"`` when ``pyoidn`` is
installed and the frame takes spp ≤ :data:`AUTO_MAX_SPP` samples per pixel; ``--preview`` always.
Measured (``bench/bench_denoise.py``, docs/rendering.md "Denoising"; 320×180, errors against a 256-spp
reference, demo and meadow): the denoised/plain relative RMSE with the guides as they are is 0.57–0.74 at
8 spp, 0.65–0.84 at 16, 0.77–0.93 at 32 and 0.87–0.98 at 64 (prefiltered: 0.59–0.75, 0.66–0.86, 0.78–0.99,
0.90–1.09) — the gain fades as the noise falls while the softened foliage (on crops at 8 and 16 spp, and at 32
on the demo) stays, so above :data:`AUTO_MAX_SPP` "auto" leaves the frame as traced.
"""

from __future__ import annotations

import atexit
import threading
from typing import Any

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


class _Oidn:
    """One OIDN CPU device for the process, created on first use and released at exit; a filter is made per run
    (cheap next to running it), one run at a time under a lock."""

    def __init__(self) -> None:
        self._device: Any = None
        self._lock = threading.Lock()
        atexit.register(self.close)

    def close(self) -> None:
        """Release the device (a later run makes a new one)."""
        with self._lock:
            if self._device is not None:
                self._device.release()
                self._device = None

    def run(self, images: dict[str, np.ndarray], *, hdr: bool, clean_aux: bool, quality: str) -> np.ndarray:
        """Run one ``RT`` filter over ``images`` (slot name → contiguous float32 (H, W, 3)); the output."""
        import pyoidn

        qualities = {
            "default": pyoidn.OIDN_QUALITY_DEFAULT,
            "fast": pyoidn.OIDN_QUALITY_FAST,
            "balanced": pyoidn.OIDN_QUALITY_BALANCED,
            "high": pyoidn.OIDN_QUALITY_HIGH,
        }
        if quality not in qualities:
            raise ValueError(f"quality must be one of {', '.join(qualities)}, got {quality!r}")
        first = next(iter(images.values()))
        out = np.empty_like(first)
        with self._lock:
            if self._device is None:
                device = pyoidn.Device()
                device.commit()
                _check(device, "device")
                self._device = device
            device = self._device
            flt = pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)
            try:
                for name, image in images.items():
                    flt.set_image(name, image, pyoidn.OIDN_FORMAT_FLOAT3)
                flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
                if "color" in images:
                    flt.set_bool("hdr", hdr)
                    flt.set_bool("cleanAux", clean_aux)
                flt.set_quality(qualities[quality])
                flt.commit()
                _check(device, "filter set-up")
                flt.execute()
                _check(device, "filter")
            finally:
                flt.release()
        return out


def _check(device: Any, what: str) -> None:
    error = device.get_error()
    if error is not None:
        raise RuntimeError(f"Open Image Denoise {what} failed: {error}")


_OIDN = _Oidn()


def denoise(
    rgb: np.ndarray,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    *,
    clean_aux: bool = False,
    prefilter: bool = False,
    quality: str = "high",
) -> np.ndarray | None:
    """Denoise linear HDR ``rgb (H, W, 3)``; None when OIDN is not installed.

    ``albedo`` and ``normal`` ``(H, W, 3)`` are passed to OIDN when given (the
    normal only together with an albedo).  ``clean_aux``: the buffers are
    noise-free (e.g. from one sample at the pixel centre with a box filter) and
    OIDN need not prefilter them; leave False for buffers averaged over the
    same noisy samples as the beauty.  ``prefilter`` (noisy guides only): denoise
    each guide first by an ``RT`` filter of that image alone, then the beauty
    with the cleaned guides and ``cleanAux`` on — OIDN's recommendation for noisy
    guides, three filter runs instead of one (320×180: about 1.2 CPU-s instead of
    0.17); off by default, as it measured worse on forest's own guides (the
    module docstring).  The same inputs give the same bytes.
    """
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        return None
    colour = np.asarray(rgb, dtype=np.float32)
    if colour.ndim != 3 or colour.shape[2] < 3:
        raise ValueError(f"denoise needs (H, W, 3) colour, got {colour.shape}")
    colour = np.ascontiguousarray(np.maximum(np.nan_to_num(colour[..., :3]), 0.0))
    alb = _rgb("albedo", albedo, colour.shape, 0.0, 1.0)
    nrm = _rgb("normal", normal, colour.shape, -1.0, 1.0) if alb is not None else None
    images = {"color": colour}
    clean = clean_aux and alb is not None
    if alb is not None and not clean and prefilter:
        alb = prefilter_guide("albedo", alb, quality=quality)
        if nrm is not None:
            nrm = prefilter_guide("normal", nrm, quality=quality)
        clean = True
    if alb is not None:
        images["albedo"] = alb
    if nrm is not None:
        images["normal"] = nrm
    return _OIDN.run(images, hdr=True, clean_aux=clean, quality=quality)


def prefilter_guide(kind: str, image: np.ndarray, *, quality: str = "high") -> np.ndarray:
    """The ``kind`` ("albedo" or "normal") guide ``image (H, W, 3)`` denoised by an ``RT`` filter of that image
    alone (OIDN's prefiltering); albedo stays in [0, 1], the normal in [−1, 1] (not renormalised, as OIDN takes it)."""
    if kind not in ("albedo", "normal"):
        raise ValueError(f"kind must be 'albedo' or 'normal', got {kind!r}")
    lo = 0.0 if kind == "albedo" else -1.0
    a = np.ascontiguousarray(np.clip(np.nan_to_num(np.asarray(image, np.float32)[..., :3]), lo, 1.0))
    out = _OIDN.run({kind: a}, hdr=False, clean_aux=False, quality=quality)
    return np.ascontiguousarray(np.clip(np.nan_to_num(out), lo, 1.0))
