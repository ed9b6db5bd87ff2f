"""The cost and the effect of the ground's macro variation (``[ground] variation``, forest.ground).

    .venv/bin/python bench/bench_ground.py

For the valley and the demo (configs/valley.toml, configs/demo.toml; their scatter run once), the Scene's
albedo grid (:func:`forest.ground.terrain_albedo`) is painted with ``variation = 0`` and with the default,
alternating, best of 3 by CPU time.  Printed: the seconds of each, their ratio, and on the grid's grass texels
(blocks painted pure grass) the standard deviation of the log luminance and of the log red/green
ratio over 8 x 8-texel blocks, against the same figures measured on the field of a photographed meadow
(tests/fixtures/photos/autumn_larch_hillside.jpg, its lowest 18 %, 8- and 16-pixel blocks).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of

LUMA = np.array([0.2126, 0.7152, 0.0722])


def block_spread(rgb: np.ndarray, mask: np.ndarray, block: int) -> tuple[float, float]:
    """(σ of log luminance, σ of log red/green) over ``block`` × ``block`` blocks lying wholly in ``mask``."""
    h, w = (s // block * block for s in rgb.shape[:2])
    b = rgb[:h, :w].reshape(h // block, block, w // block, block, 3).mean(axis=(1, 3))
    keep = mask[:h, :w].reshape(h // block, block, w // block, block).all(axis=(1, 3))
    b = b[keep]
    return float(np.log(b @ LUMA).std()), float(np.log(b[:, 0] / b[:, 1]).std())


def photo_spread(block: int) -> tuple[float, float]:
    """The same figures on the photographed meadow's field (sRGB decoded; the lowest 18 % of the frame)."""
    from PIL import Image

    srgb = np.asarray(Image.open(ROOT / "tests/fixtures/photos/autumn_larch_hillside.jpg").convert("RGB"), np.float64)
    srgb /= 255.0
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    field = lin[int(lin.shape[0] * 0.82) :]
    return block_spread(field, np.ones(field.shape[:2], bool), block)


def main() -> None:
    from forest.config import load_config
    from forest.config.schema import GROUND_MATERIALS
    from forest.ground import terrain_albedo
    from forest.scene import load_scene

    load = os.getloadavg()
    print(f"ground: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start")
    for name in ("valley", "demo"):
        path = ROOT / "configs" / f"{name}.toml"
        scene = load_scene(load_config(path))
        flat_cfg = load_config(path, overrides={"ground.variation": 0.0})
        runs = {
            key: (lambda c=cfg, s=scene: terrain_albedo(c, s.terrain, s.instances, s.species))
            for key, cfg in (("variation 0", flat_cfg), ("default", scene.config))
        }
        grids, best = best_of(runs)
        flat, varied = grids["variation 0"].rgb.astype(np.float64), grids["default"].rgb.astype(np.float64)
        # Pure grass: blocks whose every texel is the grass material in the unvaried grid.
        grass_rgb = np.asarray(GROUND_MATERIALS["grass"], np.float64)
        grass = np.abs(flat - grass_rgb).max(axis=-1) < 1e-6
        a, b = best["variation 0"][1], best["default"][1]
        s0, s1 = block_spread(flat, grass, 8), block_spread(varied, grass, 8)
        print(
            f"ground {name}: albedo grid {flat.shape[1]}x{flat.shape[0]}, {a:.2f} CPU-s without variation, {b:.2f} "
            f"with ({b / a:.2f}x); pure grass ({grass.mean():.0%} of the grid), 8x8 blocks: log luminance sigma "
            f"{s0[0]:.3f} -> {s1[0]:.3f}, log red/green sigma {s0[1]:.3f} -> {s1[1]:.3f}"
        )
    for block in (8, 16):
        lum, rg = photo_spread(block)
        print(
            f"ground photograph (meadow field, {block}-px blocks): log luminance sigma {lum:.3f}, log red/green {rg:.3f}"
        )
    load = os.getloadavg()
    print(f"ground: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at end")


if __name__ == "__main__":
    main()
