"""The cost of woods and open ground on the far hills (forest.far_cover) in forest_path (llvm_ad_rgb).

    .venv/bin/python bench/bench_far_cover.py

The demo scene (configs/demo.toml: hills past the terrain, 8 501 trees) at 480x270, 8 spp: the same
PathScene inputs with the mosaic (the default with ``horizon_hills``) and without it (``woods = false``).
The two renders alternate (best of 3 each, after one warm-up each that compiles the kernels), so a busy
machine slows both alike.  Printed: wall and CPU seconds of ``PathScene.render`` with and without, their
ratio, the mean radiance of each, and how much the mosaic changes the hills (the ratio of the two renders'
luminance over the pixels whose first hit lies over 100 m past the terrain's edge: its 5-95 % range).
"""

from __future__ import annotations

import os
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    load = os.getloadavg()
    print(f"far cover: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start; demo 480x270 8 spp")
    scene = load_scene(load_config(ROOT / "configs" / "demo.toml"))
    inputs = path_inputs(scene, width=480, height=270, spp=8)
    assert inputs.far_cover is not None
    c = scene.terrain_albedo.far_cover
    print(f"far cover: the terrain's canopy cover {c:.3f}; open ground ×{np.mean(inputs.far_cover.open):.2f}, "
          f"woods ×{np.mean(inputs.far_cover.canopy):.2f} of the far albedo (channel means)")  # fmt: skip
    scenes = {k: PathScene(inputs if k else replace(inputs, far_cover=None), "llvm_ad_rgb") for k in (False, True)}
    images: dict[bool, object] = {}
    for k, s in scenes.items():  # warm-up: compile both kernels
        images[k] = s.render(seed=1)
    best: dict[bool, tuple[float, float]] = {}
    for _ in range(3):
        for k, s in scenes.items():
            t0, c0 = time.perf_counter(), cpu_seconds()
            s.render(seed=1)
            wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
            if k not in best or cpu < best[k][1]:
                best[k] = (wall, cpu)
    xmin, zmin, xmax, zmax = scene.terrain.extent
    pos = scenes[True].layers()["position"].astype(np.float64)
    x, z = pos[..., 0], pos[..., 2]
    past = (np.maximum(np.maximum(xmin - x, x - xmax), np.maximum(zmin - z, z - zmax)) > 100.0) & (pos[..., 1] != 0)
    lum = {}
    for k, img in images.items():
        rgb = np.asarray(img.rgb, np.float64).reshape(pos.shape)  # type: ignore[attr-defined]
        lum[k] = (rgb @ np.array([0.2126, 0.7152, 0.0722]))[past]
    ratio = lum[True] / np.maximum(lum[False], 1e-12)
    lo, hi = np.percentile(ratio, [5, 95])
    print(f"far cover: {past.mean():.1%} of the frame's pixels see ground over 100 m past the terrain's edge")
    for k, name in ((False, "one colour (woods = false)"), (True, "woods and open ground")):
        wall, cpu = best[k]
        mean = float(np.asarray(images[k].rgb).mean())  # type: ignore[attr-defined]
        print(f"far cover {name:27s}: {wall:6.2f} s wall, {cpu:6.2f} CPU-s, mean {mean:.4f}")
    print(f"far cover: on those pixels the mosaic scales the luminance by {lo:.2f}-{hi:.2f} (5-95 %), "
          f"mean {ratio.mean():.3f} (same seed, hazed)")  # fmt: skip
    print(f"far cover cost: {best[True][1] / best[False][1]:.2f}x CPU, {best[True][0] / best[False][0]:.2f}x wall")
    load = os.getloadavg()
    print(f"far cover: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at end")


if __name__ == "__main__":
    main()
