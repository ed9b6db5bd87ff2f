"""Cost of the leaf cuticle's specular lobe (issue 27): the same forest_path render with and without it.

    .venv/bin/python bench/bench_sheen.py                       # 320x180, 16 spp, 60 trees
    .venv/bin/python bench/bench_sheen.py --picture docs/images/leaf_sheen.png

A small grove under a low sun, seen against the light (where the lobe shows: glints on the crowns'
rims).  "without" renders the same library species with every leaf's sheen forced to 0, which traces
the code without the lobe.  Each variant renders twice, alternating, and the faster is kept (a busy
machine slows both alike); the scene (Mitsuba traversal, buffers) is built anew each time, so the
table of the lobe's albedo is part of the build figure.  Figures are printed one per line.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENE = """
name = "sheen"
seed = 11
[terrain]
procedural = {{ size = 160.0, height = 6.0, resolution = 129 }}
[scatter]
count = {count}
min_distance = 6.0
[[species]]
model = "broadleaf"
percent = 55
[[species]]
model = "conifer"
percent = 45
[camera]
position = [0.0, 9.0, -70.0]
target = [0.0, 10.0, 20.0]
fov = 50.0
[lights]
sun = {{ elevation = 14.0, azimuth = 10.0, irradiance = 3.2, colour = [1.0, 0.9, 0.78] }}
sky = {{ radiance = 0.35, colour = [0.55, 0.7, 1.0] }}
[render]
width = {width}
height = {height}
spp = {spp}
max_depth = 4
"""


def render(config: Path, sheen: bool) -> tuple[np.ndarray, float, float]:
    """(linear RGB, build s, render s) of the config, with or without the cuticle lobe."""
    import forest.render.path.materials as materials
    from forest.config import load_config
    from forest.library import open_library
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scatter import scatter
    from forest.scene import load_scene

    original = materials.leaf_sheen
    if not sheen:
        materials.leaf_sheen = lambda _m: (0.0, 0.0)  # type: ignore[assignment]
    try:
        cfg = load_config(config)
        inst, _ = scatter(cfg)
        t0 = time.perf_counter()
        scene = PathScene(path_inputs(load_scene(cfg, inst, library=open_library())), "llvm_ad_rgb")
        t1 = time.perf_counter()
        rgb = scene.render().rgb
        return rgb, t1 - t0, time.perf_counter() - t1
    finally:
        materials.leaf_sheen = original


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--count", type=int, default=60)
    ap.add_argument("--picture", type=Path, help="write 'without | with' side by side (sRGB PNG)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "sheen.toml"
        config.write_text(SCENE.format(count=a.count, width=a.width, height=a.height, spp=a.spp))
        best: dict[bool, tuple[np.ndarray, float, float]] = {}
        for _ in range(2):
            for on in (False, True):
                r = render(config, on)
                if on not in best or r[2] < best[on][2]:
                    best[on] = r
    off, on = best[False], best[True]
    print(f"image: {a.width}x{a.height} {a.spp} spp, {a.count} trees, max_depth 4, llvm_ad_rgb")
    print(f"build without: {off[1]:.2f} s, with: {on[1]:.2f} s")
    print(f"render without: {off[2]:.2f} s, with: {on[2]:.2f} s, ratio {on[2] / off[2]:.2f}")
    print(f"mean radiance without: {off[0].mean():.5f}, with: {on[0].mean():.5f} ({on[0].mean() / off[0].mean():.3f}x)")
    if a.picture:
        from forest.images import linear_to_srgb, write_image

        gap = np.ones((a.height, 4, 3), np.float32)
        side = np.concatenate([off[0], gap, on[0]], axis=1)
        write_image(a.picture, np.clip(linear_to_srgb(np.clip(side * 1.6, 0, 1)), 0, 1).astype(np.float32))
        print(f"picture: {a.picture} (without | with)")


if __name__ == "__main__":
    main()
