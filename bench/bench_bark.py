"""Cost of the per-tree bark (hue/value jitter and moss, issue 27): the same render with and without it.

    .venv/bin/python bench/bench_bark.py                        # 320x180, 16 spp, 160 trees
    .venv/bin/python bench/bench_bark.py --picture docs/images/bark_moss.png

A grove seen from among its trunks under a low sun (where bark fills a good share of the frame).
"without" sets ``bark = { hue = 0, value = 0, moss = [0, 0] }`` on every species, which is the
scene without a bark table at all (``Scene.bark_tints()`` is None); "with" keeps the defaults.
forest_path, whole render (scatter, scene build and render) timed by ``timing.best_of``: one warm-up
each, then alternating rounds, the fastest by CPU kept.  scalar_rgb shares its colour bins between the leaves'
jitter and the bark (``forest.render.instancing.JitterBins``), so the bark costs no shapegroup
there but takes bins from the leaves: the script prints the leaves' Oklab error to their bins'
colours on the demo's trees with and without the bark, and its shapegroup count.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_sheen import render as sheen_render
from timing import best_of, versus

SCENE = """
name = "bark"
seed = 11
[terrain]
procedural = {{ size = 80.0, height = 2.0, resolution = 129 }}
[scatter]
count = {count}
min_distance = 5.0
[[species]]
model = "broadleaf"
percent = 55
{bark}
[[species]]
model = "conifer"
percent = 45
{bark}
[camera]
position = [0.0, 1.7, -6.0]
target = [0.0, 3.5, 20.0]
fov = 60.0
[lights]
sun = {{ elevation = 25.0, azimuth = 150.0, irradiance = 3.2, colour = [1.0, 0.9, 0.78] }}
sky = {{ radiance = 0.35, colour = [0.55, 0.7, 1.0] }}
[render]
width = {width}
height = {height}
spp = {spp}
max_depth = 4
"""
OFF = "bark = { hue = 0.0, value = 0.0, moss = [0.0, 0.0] }"


def render(config: Path) -> np.ndarray:
    """Linear RGB of the config with forest_path (scatter, scene build, render): bench_sheen's render with the
    leaves' sheen as the config has it."""
    return sheen_render(config, True)[0]


def scalar_bins(bark: bool) -> tuple[float, float, float, int]:
    """On the demo's trees: the leaves' and the bark's rms Oklab distance to their bins' colours (8 bins per
    species, the lightest prototypes' count), the bark's to its species' mean (no bins), and the shapegroups
    of its first frame, ``bark`` on or off."""
    from forest.config import load_config
    from forest.render.instancing import ForestBuilder
    from forest.render.materials import MaterialBuilder
    from forest.scene import load_scene
    from forest.tint import oklab

    cfg = load_config(ROOT / "configs" / "demo.toml")
    if not bark:
        cfg = cfg.with_overrides({f"species[{i}].bark": {"moss": [0.0, 0.0], "hue": 0.0, "value": 0.0}
                                  for i in range(len(cfg.species))})  # fmt: skip
    scene = load_scene(cfg)
    builder = ForestBuilder(scene, MaterialBuilder("scalar_rgb", None, scene.terrain.extent,
                                                   scene.terrain.height_range))  # fmt: skip
    graph = builder.graph(scene.levels(0.0), scene.instances.matrices())
    jb = builder.jitter
    assert jb is not None
    bins, leaf = jb.bins(8)
    barks = jb.bark_factors(8)
    from forest.tint import bark_colour, leaf_colour

    s = scene.instances.species.astype(np.int64)
    ok = bins >= 0
    base = np.array([leaf_colour(sp) for sp in scene.species])[s]
    err_leaf = oklab(base[ok] * jb.jitter[ok]) - oklab(base[ok] * leaf[s[ok], bins[ok]])
    bb = np.array([bark_colour(sp) or (0.1, 0.1, 0.1) for sp in scene.species])[s]
    truth = scene.bark_tints()
    truth = np.ones((len(s), 3)) if truth is None else truth
    err_bark = oklab(bb[ok] * truth[ok]) - oklab(bb[ok] * barks[s[ok], bins[ok]])
    mean = np.array([truth[s == k].mean(axis=0) if (s == k).any() else np.ones(3) for k in range(len(scene.species))])
    err_flat = oklab(bb[ok] * truth[ok]) - oklab(bb[ok] * mean[s[ok]])  # the species' mean bark, unbinned
    rms = lambda e: float(np.sqrt((e**2).sum(axis=1).mean()))  # noqa: E731
    return rms(err_leaf), rms(err_bark), rms(err_flat), graph.shapegroups


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--count", type=int, default=160)
    ap.add_argument("--picture", type=Path, help="write 'without | with' side by side (sRGB PNG)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        configs = {}
        for on in (False, True):
            configs[on] = Path(tmp) / f"bark_{on}.toml"
            configs[on].write_text(
                SCENE.format(count=a.count, width=a.width, height=a.height, spp=a.spp, bark="" if on else OFF)
            )
        images, best = best_of({on: (lambda on=on: render(configs[on])) for on in (False, True)}, rounds=2)
    off, on = images[False], images[True]
    print(f"image: {a.width}x{a.height} {a.spp} spp, {a.count} trees, max_depth 4, llvm_ad_rgb")
    print(f"bark without: {versus(best[False], best[False], 'without')}")
    print(f"bark with   : {versus(best[True], best[False], 'without')}")
    print(f"mean radiance without: {off.mean():.5f}, with: {on.mean():.5f} ({on.mean() / off.mean():.3f}x)")
    for bark in (False, True):
        leaf, bk, flat, groups = scalar_bins(bark)
        print(f"scalar_rgb demo, bark {'on ' if bark else 'off'}: leaf rms Oklab error to its bin {leaf:.4f}, "
              f"bark {bk:.4f} (unbinned {flat:.4f}), shapegroups {groups}")  # fmt: skip
    if a.picture:
        from forest.images import linear_to_srgb, write_image

        gap = np.ones((a.height, 4, 3), np.float32)
        side = np.concatenate([off, gap, on], axis=1)
        write_image(a.picture, np.clip(linear_to_srgb(np.clip(side * 1.6, 0, 1)), 0, 1).astype(np.float32))
        print(f"picture: {a.picture} (without | with)")


if __name__ == "__main__":
    main()
