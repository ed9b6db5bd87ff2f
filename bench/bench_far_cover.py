"""The cost of woods and open ground on the far hills (forest.far_cover) in forest_path (llvm_ad_rgb).

    .venv/bin/python bench/bench_far_cover.py

The demo scene (configs/demo.toml: hills past the terrain, 8 501 trees) at 480x270, 8 spp: the same
PathScene inputs with the woods (the default with ``horizon_hills``: the mosaic and the woods' relief), with
the mosaic alone (the relief's height set to 0) and without either (``woods = false``).  The renders
alternate (best of 3 each, after one warm-up each that compiles the kernels), so a busy machine slows all
alike.  Printed: the skirt's triangles and the CPU seconds to build each PathScene (the skirt's mesh is built
there), wall and CPU seconds of ``PathScene.render``, their ratios to the one colour, the mean radiance of
each, how much the mosaic changes the hills (the ratio of the renders' luminance over the pixels whose first
hit lies over 100 m past the terrain's edge: its 5-95 % range), and the share of the frame the relief turns
from sky to ground.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of, cpu_seconds, versus


def main() -> None:
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene
    from forest.skirt import relief_step, skirt_mesh

    load = os.getloadavg()
    print(f"far cover: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start; demo 480x270 8 spp")
    scene = load_scene(load_config(ROOT / "configs" / "demo.toml"))
    inputs = path_inputs(scene, width=480, height=270, spp=8)
    assert inputs.far_cover is not None
    c = scene.terrain_albedo.far_cover
    print(f"far cover: the terrain's wooded land {c:.3f}; open ground ×{np.mean(inputs.far_cover.open):.2f}, "
          f"woods ×{np.mean(inputs.far_cover.canopy):.2f} of the far albedo (channel means)")  # fmt: skip
    fc = inputs.far_cover
    variants = {
        "one colour (woods = false)": replace(inputs, far_cover=None),
        "mosaic, no relief": replace(inputs, far_cover=replace(fc, height=0.0)),
        "woods (mosaic + relief)": inputs,
    }
    names = list(variants)
    scenes, build = {}, {}
    for _ in range(2):  # the first round also reads the species' meshes: the better of two, alternating
        for name, inp in variants.items():
            scenes.pop(name, None)
            t0, c0 = time.perf_counter(), cpu_seconds()
            scenes[name] = PathScene(inp, "llvm_ad_rgb")
            took = (time.perf_counter() - t0, cpu_seconds() - c0)
            build[name] = min(build.get(name, took), took)
    step = relief_step(inputs.camera.fov, inputs.camera.width)
    skirt = skirt_mesh(scene.terrain, inputs.skirt_radius, inputs.skirt_hills, fc, step)
    plain = skirt_mesh(scene.terrain, inputs.skirt_radius, inputs.skirt_hills)
    assert skirt is not None and plain is not None
    print(f"far cover: the woods' canopy height {fc.height:.1f} m; skirt {len(plain.faces):,} triangles without the "
          f"relief, {len(skirt.faces):,} with it (every {np.degrees(step):.3f}° around)")  # fmt: skip
    images, best = best_of({name: (lambda s=s: s.render(seed=1)) for name, s in scenes.items()})
    xmin, zmin, xmax, zmax = scene.terrain.extent
    pos = scenes[names[1]].layers()["position"].astype(np.float64)
    x, z = pos[..., 0], pos[..., 2]
    past = (np.maximum(np.maximum(xmin - x, x - xmax), np.maximum(zmin - z, z - zmax)) > 100.0) & (pos[..., 1] != 0)
    lum = {}
    for name in names[:2]:
        rgb = np.asarray(images[name].rgb, np.float64).reshape(pos.shape)  # type: ignore[attr-defined]
        lum[name] = (rgb @ np.array([0.2126, 0.7152, 0.0722]))[past]
    ratio = lum[names[1]] / np.maximum(lum[names[0]], 1e-12)
    lo, hi = np.percentile(ratio, [5, 95])
    print(f"far cover: {past.mean():.1%} of the frame's pixels see ground over 100 m past the terrain's edge")
    base_wall, base_cpu = best[names[0]]
    for name in names:
        mean = float(np.asarray(images[name].rgb).mean())  # type: ignore[attr-defined]
        print(f"far cover {name:27s}: build {build[name][0]:5.2f} s wall, {build[name][1]:5.2f} CPU-s; render "
              f"{versus(best[name], best[names[0]], 'the one colour')}, mean {mean:.4f}")  # fmt: skip
    print(f"far cover: on those pixels the mosaic scales the luminance by {lo:.2f}-{hi:.2f} (5-95 %), "
          f"mean {ratio.mean():.3f} (same seed, hazed)")  # fmt: skip
    sky = {n: scenes[n].layers()["row"] < 0 for n in names[1:]}
    print(f"far cover: the relief turns {np.mean(sky[names[1]] & ~sky[names[2]]):.2%} of the frame from sky to "
          f"ground, {np.mean(~sky[names[1]] & sky[names[2]]):.2%} the other way")  # fmt: skip
    print(f"far cover cost: woods {best[names[2]][1] / base_cpu:.2f}x CPU, {best[names[2]][0] / base_wall:.2f}x wall; "
          f"relief alone {best[names[2]][1] / best[names[1]][1]:.2f}x CPU")  # fmt: skip
    load = os.getloadavg()
    print(f"far cover: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at end")


if __name__ == "__main__":
    main()
