"""Judge a fitted look the way a user uses it: render the written scene and a truth alike, from other views.

A fit's own objective compares the reference with renders at the reference's camera
and light — the quantity it minimised, so it cannot show what the fit got wrong where
the reference is silent: a colour map that is flat where the reference had patches,
a sky never in frame, albedos traded against the light.  :func:`compare` renders two
scenes — typically the ``scene.toml`` that ``forest match`` wrote and a truth (a
production scene with the look the reference was made from) — with the production
renderer, in the same *views*: the reference's camera, new cameras, new suns (each a
set of config overrides applied to both), and reports each view's mean per-pixel
CIEDE2000.

**Exposure.**  Both images are multiplied by one factor, k = 0.18 / mean Y(truth): a
camera's middle-grey exposure of the truth, so CIELAB's lightness is where its
steps are meaningful; the comparison stays absolute (both take the same k).

**Noise.**  Two Monte-Carlo renders of one scene differ per pixel by their noise
(ΔE 1–2 at 256 spp on a foliage frame).  The two scenes are therefore rendered with
the same seeds — common random numbers: the same pixel samples and the same random
decisions where the looks agree, so the noise largely cancels in the difference and
what remains is the looks' difference — and the truth is also rendered with another
seed, whose difference from the first is the *floor*: what independent noise alone
would give (reported beside each figure; a figure below it is not a sign of error).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .colour import delta_e2000, luminance

if TYPE_CHECKING:
    from ..scene import Scene

#: The middle grey both images of a comparison are exposed to (the truth's mean luminance).
MIDDLE_GREY = 0.18


@dataclass(frozen=True)
class ViewFigure:
    """One view of a comparison: mean per-pixel CIEDE2000 with common random numbers, and the noise floor."""

    name: str
    delta_e: float
    floor: float


def exposed_delta_e(image: np.ndarray, truth: np.ndarray) -> float:
    """Mean per-pixel CIEDE2000 of two linear images, both exposed by k = :data:`MIDDLE_GREY` / mean Y(truth)."""
    k = MIDDLE_GREY / max(float(np.mean(luminance(truth))), 1e-12)
    return float(np.mean(delta_e2000((image * k).reshape(-1, 3), (truth * k).reshape(-1, 3))))


def render_view(
    scene: Scene, overrides: Mapping[str, Any], *, width: int, height: int, spp: int, seed: int, variant: str
) -> np.ndarray:
    """The production render of ``scene`` with config ``overrides`` (linear (H, W, 3))."""
    from .report import Production

    view = scene.with_config(scene.config.with_overrides(dict(overrides))) if overrides else scene
    return Production(view, variant).image(width=width, height=height, spp=spp, seed=seed)


def compare(
    fitted: Any,
    truth: Any,
    views: Mapping[str, Mapping[str, Any]],
    *,
    width: int,
    height: int,
    spp: int,
    variant: str = "llvm_ad_rgb",
    seed: int = 21,
    render: Callable[..., np.ndarray] | None = None,
    images: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> list[ViewFigure]:
    """Each view's :class:`ViewFigure` for two scenes rendered alike (module docstring).

    ``views`` maps a name to config overrides applied to both (``{}``: as they are).  By default ``fitted`` and
    ``truth`` are Scenes with the same trees, rendered by :func:`render_view`; ``render(thing, overrides, seed)``
    renders anything else (a config file through ``forest render``, say).  ``images``, when given, receives
    ``{name: (fitted, truth)}``."""
    if render is None:

        def render(thing: Any, overrides: Mapping[str, Any], seed: int) -> np.ndarray:
            return render_view(thing, overrides, width=width, height=height, spp=spp, seed=seed, variant=variant)

    out = []
    for name, ov in views.items():
        t = render(truth, ov, seed)
        f = render(fitted, ov, seed)
        t2 = render(truth, ov, seed + 1)
        out.append(ViewFigure(name, exposed_delta_e(f, t), exposed_delta_e(t2, t)))
        if images is not None:
            images[name] = (f, t)
    return out


def pattern_correlation(fitted: np.ndarray, truth: np.ndarray, keep: np.ndarray | None = None) -> float:
    """Pearson correlation of two colour maps' per-cell log colours, each channel's mean removed (the pattern,
    not its overall tint): ``fitted`` is sampled at ``truth``'s cell centres (bilinear, as rendered); ``keep``
    (truth's shape, bool) limits it to some cells."""
    from ..maps import sample_bilinear

    n, m = truth.shape[:2]
    u, v = np.meshgrid((np.arange(m) + 0.5) / m, (np.arange(n) + 0.5) / n)
    f = np.asarray(sample_bilinear(np.asarray(fitted, np.float64), u.ravel(), v.ravel())).reshape(n, m, 3)
    a = np.log(np.maximum(f, 1e-9))
    b = np.log(np.maximum(np.asarray(truth, np.float64), 1e-9))
    if keep is not None:
        a, b = a[keep], b[keep]
    a = a.reshape(-1, 3) - a.reshape(-1, 3).mean(axis=0)
    b = b.reshape(-1, 3) - b.reshape(-1, 3).mean(axis=0)
    return float((a * b).sum() / max(np.sqrt((a * a).sum() * (b * b).sum()), 1e-30))


def covered_cells(
    layers: dict[str, np.ndarray], labels: np.ndarray, shape: tuple[int, int], least: int = 4
) -> np.ndarray:
    """(n, m) bool: the cells of an n×m map over the terrain that hold at least ``least`` canopy pixels of a
    render's layers (:attr:`.renders.FitRenderer.layers`, :func:`.regions.render_labels`)."""
    from .regions import CANOPY

    n, m = shape
    c = labels == CANOPY
    u, v = layers["u"][c], layers["v"][c]
    ok = np.isfinite(u) & np.isfinite(v)
    i = np.clip((v[ok] * n).astype(np.int64), 0, n - 1)
    j = np.clip((u[ok] * m).astype(np.int64), 0, m - 1)
    return (np.bincount(i * m + j, minlength=n * m) >= least).reshape(n, m)


__all__ = ["MIDDLE_GREY", "ViewFigure", "compare", "covered_cells", "exposed_delta_e", "pattern_correlation"]
