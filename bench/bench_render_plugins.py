"""Cost of forest's Python Mitsuba plugins per variant (the leaf BSDF with diffuse transmission).

Python plugins are traced once per kernel in the JIT variants but called once
per sample in ``scalar_rgb``.  This renders the same card scene with the
``forest_leaf`` plugin and with Mitsuba's native two-sided ``diffuse`` in
``scalar_rgb`` and ``llvm_ad_rgb`` and prints the time ratio — the figure
behind ``forest.render.materials`` using native BSDFs in ``scalar_rgb``.

    .venv/bin/python bench/bench_render_plugins.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def scene_dict(mi, bsdf: dict, cards: int = 64) -> dict:
    T = mi.ScalarTransform4f
    rng = np.random.default_rng(1)
    d = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {
            "type": "perspective",
            "fov": 45,
            "to_world": T().look_at(origin=[0, 0, -12], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 160, "height": 120, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 16},
        },
        "sun": {"type": "directional", "direction": [0.3, -0.6, 0.7], "irradiance": 3.0},
        "sky": {"type": "constant", "radiance": 0.3},
        "leaf": bsdf,
    }
    for k in range(cards):
        x, y, z = rng.uniform(-4, 4, 3)
        a, b = rng.uniform(0, 360, 2)
        d[f"card_{k}"] = {
            "type": "rectangle",
            "bsdf": {"type": "ref", "id": "leaf"},
            "to_world": T().translate([x, y, z]).rotate([0, 1, 0], a).rotate([1, 0, 0], b).scale(0.8),
        }
    return d


def timed(mi, scene, repeat: int = 2) -> float:
    np.asarray(mi.render(scene, spp=1))  # compile / warm up (np.asarray forces JIT evaluation)
    best = float("inf")
    for i in range(repeat):
        t = time.perf_counter()
        np.asarray(mi.render(scene, seed=i))
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    from forest.runtime import mitsuba

    leaf = {
        "type": "forest_leaf",
        "reflectance": {"type": "rgb", "value": [0.1, 0.3, 0.05]},
        "transmittance": {"type": "rgb", "value": [0.05, 0.15, 0.02]},
    }
    native = {
        "type": "twosided",
        "material": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.15, 0.45, 0.07]}},
    }
    samples = 160 * 120 * 16
    for variant in ("scalar_rgb", "llvm_ad_rgb"):
        mi = mitsuba(variant)
        t_leaf = timed(mi, mi.load_dict(scene_dict(mi, leaf)))
        t_native = timed(mi, mi.load_dict(scene_dict(mi, native)))
        print(
            f"render plugins {variant}: forest_leaf {t_leaf:.2f} s, native twosided diffuse {t_native:.2f} s "
            f"({samples:,} samples): the Python BSDF costs {t_leaf / t_native:.1f}× "
            f"({(t_leaf - t_native) / samples * 1e6:.2f} µs per sample)"
        )


if __name__ == "__main__":
    main()
