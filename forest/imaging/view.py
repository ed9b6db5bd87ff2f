"""The view transform: scene-linear renders → sRGB display pictures, through OpenColorIO.

``to_display(rgb, view="agx", exposure=0.0)`` multiplies the scene-linear image by
``2^exposure`` (OCIO's ExposureContrastTransform, linear style) and applies the
``sRGB`` display's view from forest's shipped OCIO config (see
:mod:`forest.imaging.curves` for the maths and :mod:`forest.imaging.ocio_config`
for the config), on OCIO's CPU processor over the whole numpy array.

Where 18 % grey lands at exposure 0 (sRGB code values; ×255 for 8-bit):

========  =====================  ==============================================
view      18 % grey →            highlights
========  =====================  ==============================================
agx       0.500 (127.5/255)      roll off to white at +6.5 EV (scene 16.3)
filmic    0.500 (127.5/255)      roll off to white at +4.1 EV (scene 3.12)
standard  0.461 (117.7/255)      clip at scene 1.0 (+2.5 EV)
aces      0.356 (90.8/255)       ACES 1.x RRT + SDR video ODT (OCIO built-in):
                                 scene 1 → 0.81, 4 → 0.955, 16 → 0.9997
========  =====================  ==============================================

Each +1 EV of ``exposure`` doubles the scene values before the view, so grey at
+1 EV is the value grey·2 has at 0 EV.  Only display pictures (PNG, previews) go
through a view; the EXR stays scene-linear and says so in its header.
"""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..parallel import blockwise
from . import ocio_config as _cfg

VIEWS = ("agx", "filmic", "standard", "aces")
"""The values ``[render] view`` accepts."""
DEFAULT_VIEW = "agx"
LOOKS = ("none", *_cfg.LOOK_NAMES)
"""The values ``[render] look`` accepts: none, or one of Blender's AgX looks (agx view only)."""
EXPOSURE_RANGE = (-10.0, 10.0)
"""The exposures (EV) ``[render] exposure`` accepts: ±10 stops covers any sane render
(beyond it the image is a flat black or white in every view)."""

CONFIG_PATH = Path(__file__).resolve().parent / "ocio" / "config.ocio"
"""forest's shipped OCIO config (package data)."""


def check_view(view: Any, *, path: str | Path | None = None, field: str = "render.view") -> str:
    """``view`` as one of :data:`VIEWS` (case-insensitive), or :class:`ConfigError` naming ``field``."""
    if not isinstance(view, str) or view.strip().lower() not in VIEWS:
        raise ConfigError(path, field, f"unknown view {view!r}; use one of {', '.join(VIEWS)}")
    return view.strip().lower()


def check_exposure(exposure: Any, *, path: str | Path | None = None, field: str = "render.exposure") -> float:
    """``exposure`` as a float in :data:`EXPOSURE_RANGE`, or :class:`ConfigError` naming ``field``."""
    lo, hi = EXPOSURE_RANGE
    if isinstance(exposure, bool) or not isinstance(exposure, (int, float, np.integer, np.floating)):
        raise ConfigError(path, field, f"exposure must be a number of stops (EV), not {exposure!r}")
    value = float(exposure)
    if not math.isfinite(value) or not lo <= value <= hi:
        raise ConfigError(path, field, f"exposure {exposure!r} EV is out of range; use {lo:g} to {hi:g}")
    return value


@functools.lru_cache(maxsize=1)
def load_ocio_config():
    """forest's OCIO config (``PyOpenColorIO.Config``), loaded once."""
    import PyOpenColorIO as OCIO

    return OCIO.Config.CreateFromFile(str(CONFIG_PATH))


def check_look(
    look: Any, view: str = DEFAULT_VIEW, *, path: str | Path | None = None, field: str = "render.look"
) -> str:
    """``look`` as one of :data:`LOOKS` (case-insensitive) that ``view`` takes (a look other than ``none`` grades
    the agx view), or :class:`ConfigError` naming ``field``."""
    if not isinstance(look, str) or look.strip().lower() not in LOOKS:
        raise ConfigError(path, field, f"unknown look {look!r}; use one of {', '.join(LOOKS)}")
    look = look.strip().lower()
    if look != "none" and view != "agx":
        raise ConfigError(path, field, f'look {look!r} grades the agx view; the view is {view!r} (use view = "agx")')
    return look


@functools.lru_cache(maxsize=32)
def _processor(view: str, exposure: float, look: str = "none"):
    import PyOpenColorIO as OCIO

    steps = [OCIO.ExposureContrastTransform(style=OCIO.EXPOSURE_CONTRAST_LINEAR, exposure=exposure)]
    if look != "none":
        steps.append(OCIO.LookTransform(src=_cfg.SCENE_LINEAR, dst=_cfg.SCENE_LINEAR, looks=_cfg.LOOK_NAMES[look]))
    steps.append(OCIO.DisplayViewTransform(src=_cfg.SCENE_LINEAR, display=_cfg.DISPLAY, view=_cfg.VIEW_NAMES[view]))
    return load_ocio_config().getProcessor(OCIO.GroupTransform(steps)).getDefaultCPUProcessor()


def to_display(rgb: np.ndarray, view: str = DEFAULT_VIEW, exposure: float = 0.0, look: str = "none") -> np.ndarray:
    """Scene-linear Rec.709 RGB ``(..., 3|4)`` → sRGB display code values, float32 in [0, 1].

    Only the first three channels are transformed (an alpha channel is dropped).
    NaN becomes 0 and +inf the largest float first, so a stray sample never
    poisons the picture.  ``look``: one of :data:`LOOKS`, graded on the agx view's
    log encoding (:mod:`forest.imaging.curves`, "Looks").  Raises
    :class:`ConfigError` for an unknown ``view`` or ``look``, a look on another
    view, or an ``exposure`` outside :data:`EXPOSURE_RANGE`.
    """
    view = check_view(view)
    exposure = check_exposure(exposure)
    look = check_look(look, view)
    arr = np.asarray(rgb)
    if arr.ndim < 1 or arr.shape[-1] < 3:
        raise ValueError(f"to_display needs (..., 3) RGB, got shape {arr.shape}")
    out = np.nan_to_num(arr[..., :3], nan=0.0, posinf=float(np.finfo(np.float32).max), neginf=0.0)
    out = np.ascontiguousarray(out, dtype=np.float32)
    if out.size:
        flat = out.reshape(-1, 3)
        processor = _processor(view, exposure, look)  # OCIO's CPU processors are thread-safe; blocks in threads
        blockwise(lambda lo, hi: processor.applyRGB(flat[lo:hi]), len(flat))
    return np.clip(out, 0.0, 1.0, out=out)


def quantise(display: np.ndarray, bits: int = 8) -> np.ndarray:
    """Display code values in [0, 1] → ``uint8`` (bits = 8) or ``uint16`` (bits = 16), rounded to nearest."""
    if bits not in (8, 16):
        raise ValueError("bits must be 8 or 16")
    top = (1 << bits) - 1
    q = np.rint(np.clip(display, 0.0, 1.0) * top)
    return q.astype(np.uint8 if bits == 8 else np.uint16)


def write_display(
    path: str | Path,
    rgb: np.ndarray,
    *,
    view: str = DEFAULT_VIEW,
    exposure: float = 0.0,
    bits: int = 8,
    attributes: dict | None = None,
    look: str = "none",
) -> Path:
    """Write the view of scene-linear ``rgb`` to a PNG (8 or 16 bit), atomically.

    The header records the view, exposure and look (``forest:view``, ``forest:exposure``, ``forest:look``).
    """
    from ..images import write_encoded_image

    view = check_view(view)
    look = check_look(look, view)
    display = to_display(rgb, view, exposure, look)
    attrs = {"forest:view": view, "forest:exposure": float(exposure), **(attributes or {})}
    if look != "none":
        attrs["forest:look"] = look
    return write_encoded_image(path, quantise(display, bits), attributes=attrs)


os.environ.setdefault("OCIO_LOGGING_LEVEL", "warning")
