"""What a look-dev run writes: the fitted scene config, the colour map, the figures and report.png.

* ``scene.toml`` — the input config with ``[maps] colour`` pointing at the
  fitted map (``colour_map.exr``, float linear RGB in the map convention,
  beside it) and the fitted light values written into ``[lights]``.  Paths the
  input config named relative to its own folder are rewritten relative to the
  output folder, so the new file renders the same scene from where it lies.
* ``report.png`` — reference, start and result side by side (sRGB), the loss
  curve, the per-parameter trajectories and the colour error (mean and 95th
  percentile CIEDE2000).
* ``match.json`` — the same figures as numbers.

Values are rounded (lights to 6 significant digits, the map to 1/65536)
so that the files do not depend on the last bits of a floating-point sum.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..config import rebase_paths
from ..images import linear_to_srgb, write_image
from .state import LookState

MAP_NAME = "colour_map.exr"


def _round(x: float, digits: int = 6) -> float:
    return float(f"{float(x):.{digits}g}")


def rounded_grid(grid: np.ndarray) -> np.ndarray:
    return (np.round(np.clip(grid, 0.0, 1.0) * 65536.0) / 65536.0).astype(np.float32)


def scene_data(config, state: LookState, fitted: tuple[str, ...], out_dir: Path, map_name: str = MAP_NAME) -> dict:
    """The fitted config as a TOML-ready dict."""
    data = rebase_paths(config.data, Path(config.base_dir), Path(out_dir))
    if "colour_map" in fitted:
        data.setdefault("maps", {})["colour"] = map_name
    lights = data.setdefault("lights", {})
    if state.sun_irradiance is not None and ("sun" in fitted or "sun_direction" in fitted):
        sun = lights.setdefault("sun", {})
        if "sun" in fitted:
            sun["irradiance"] = _round(state.sun_irradiance)
            sun["colour"] = [_round(c) for c in state.sun_colour]
        if "sun_direction" in fitted:
            sun["elevation"] = _round(state.sun_elevation)
            sun["azimuth"] = _round(state.sun_azimuth)
    if "sky" in fitted and state.sky_kind is not None:
        sky = lights.setdefault("sky", {})
        if state.sky_kind == "constant":
            sky["radiance"] = _round(state.sky_radiance)
            sky["colour"] = [_round(c) for c in state.sky_colour]
        elif state.sky_kind == "envmap":
            sky["scale"] = _round(state.envmap_scale)
        elif state.sky_kind == "sunsky":
            sky.setdefault("sunsky", {})["scale"] = _round(state.envmap_scale)
    return data


def write_scene(path: Path, data: dict) -> Path:
    import tomli_w

    text = "# look-dev result: colour map and light values fitted to a reference (forest match)\n" + tomli_w.dumps(data)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_json(path: Path, data: dict) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path


def _show(img: np.ndarray) -> np.ndarray:
    return linear_to_srgb(np.clip(img, 0.0, 1.0))


def write_report(
    path: Path,
    *,
    reference: np.ndarray,
    start: np.ndarray,
    result: np.ndarray,
    losses: list[float],
    trajectories: dict[str, list[float]],
    figures: dict,
    title: str,
) -> Path:
    """report.png: three images on top, loss curve and trajectories below, figures in the title."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 8.5), dpi=100)
    gs = fig.add_gridspec(2, 3, height_ratios=[1.0, 1.0], hspace=0.35, wspace=0.25)
    for i, (name, img) in enumerate((("reference", reference), ("start", start), ("result", result))):
        ax = fig.add_subplot(gs[0, i])
        ax.imshow(_show(img), interpolation="nearest")
        label = name
        if name in ("start", "result"):
            label += f"  ΔE00 mean {figures[name + '_delta_e_mean']:.2f}, p95 {figures[name + '_delta_e_p95']:.2f}"
        ax.set_title(label, fontsize=9)
        ax.axis("off")
    ax = fig.add_subplot(gs[1, 0])
    ax.plot(np.arange(1, len(losses) + 1), losses, lw=0.8, color="k")
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_title("loss", fontsize=9)
    ax1 = fig.add_subplot(gs[1, 1])
    ax2 = fig.add_subplot(gs[1, 2])
    for name, values in sorted(trajectories.items()):
        v = np.asarray(values, dtype=np.float64)
        target = ax2 if "colour" in name else ax1
        ref = v[0] if abs(v[0]) > 1e-12 else 1.0
        target.plot(np.arange(1, len(v) + 1), v / ref if target is ax1 else v, lw=0.8, label=name)
    ax1.set_title("light values (relative to start)", fontsize=9)
    ax2.set_title("colours (map mean, light chromaticities)", fontsize=9)
    for a in (ax1, ax2):
        a.set_xlabel("iteration")
        if a.lines:
            a.legend(fontsize=6, loc="best")
    fig.suptitle(title, fontsize=10)
    with atomic_path(path) as tmp:
        fig.savefig(str(tmp), format="png", metadata={"Software": None})
    return path


def write_map(path: Path, grid: np.ndarray) -> Path:
    return write_image(path, rounded_grid(grid), half=False)
