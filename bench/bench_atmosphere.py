"""Aerial perspective: the clear sky's colour through the haze, and what the valley fog costs.

    .venv/bin/python bench/bench_atmosphere.py                 # both cases
    .venv/bin/python bench/bench_atmosphere.py --case sky

Cases:

* ``sky`` — the demo's sky (sunsky, turbidity 3, the sun at 32° elevation, azimuth 240°)
  seen from 95 m above the ground, looking up 25° away from the sun (fov 60°), with no
  geometry: the mean HSV saturation and hue of the sky pixels, clear and through a haze of
  ground extinction σ₀ at several scale heights H.  The sky ray crosses the column, so its
  optical depth toward elevation θ is ≈ σ₀·H·e^(−h/H)/sin θ (h the camera's height).
* ``cost`` — the demo at 160×90, 4 spp, forest_path (llvm_ad_rgb): seconds per frame
  with the haze only, with a valley fog added (a level top) and with fog banks (a top that varies by
  8 m) (best of 5 alternating renders after a warm-up).
* ``shafts`` — light shafts (``[render] haze_shafts``) against the lit haze on the demo, the ecosystem and
  the valley at 320×180, 8 spp: seconds per frame and the change of the frame's mean.

Figures are printed one per line.
"""

from __future__ import annotations

import argparse
import colorsys
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VARIANT = "llvm_ad_rgb"


def look(position, target) -> np.ndarray:
    """Camera→world 4×4 looking from ``position`` at ``target`` (+Y up, +X left)."""
    p, t = np.asarray(position, float), np.asarray(target, float)
    z = (t - p) / np.linalg.norm(t - p)
    x = np.cross((0.0, 1.0, 0.0), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, p
    return m


def ground_quad(half: float = 10.0):
    """A small horizontal square at y = 0 (normals up), as MeshData: the scene needs one surface."""
    from forest.library.mesh import MeshData

    v = np.array([[-half, 0.0, -half], [half, 0.0, -half], [half, 0.0, half], [-half, 0.0, half]], np.float32)
    n = np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return MeshData(v, np.array([[0, 2, 1], [0, 3, 2]], np.uint32), n, uv)


def sky_image(haze, *, width: int = 48, height: int = 32, spp: int = 4) -> np.ndarray:
    """The demo's sunsky seen up and away from the sun through ``haze`` (HazeInputs or None), linear RGB."""
    from forest.instances import InstanceSet
    from forest.lights import sun_vector
    from forest.render.path import Material, PathCamera, PathInputs, PathScene, SkyLight, SunLight, Surface

    sun_dir = sun_vector(32.0, 240.0)
    away = -np.array([sun_dir[0], 0.0, sun_dir[2]])
    away /= np.linalg.norm(away)
    target = np.array([0.0, 95.0, 0.0]) + 100.0 * (away * np.cos(np.radians(25.0)) + [0, np.sin(np.radians(25.0)), 0])
    inst = InstanceSet.empty(species_names=("none",))
    inputs = PathInputs(
        instances=inst,
        species=[None],
        levels=np.zeros(0, np.int64),
        matrices=np.zeros((0, 4, 4)),
        camera=PathCamera(look([0.0, 95.0, 0.0], target), 60.0, width, height),
        surfaces=[Surface(ground_quad(), Material("surface", (0.2, 0.2, 0.2)))],  # out of view, below
        sun=SunLight(sun_dir, (4.5, 4.2, 3.7)),
        sky=SkyLight("sunsky", turbidity=3.0),
        max_depth=1,
        spp=spp,
        haze=haze,
    )
    return np.asarray(PathScene(inputs, VARIANT).render().rgb, np.float64)


def saturation_hue(rgb: np.ndarray) -> tuple[float, float]:
    """Mean HSV saturation and hue (degrees) of the pixels (linear RGB, as rendered)."""
    px = rgb.reshape(-1, 3)
    hsv = np.array([colorsys.rgb_to_hsv(*p) for p in px])
    return float(hsv[:, 1].mean()), float(np.degrees(np.angle(np.exp(2j * np.pi * hsv[:, 0]).mean())) % 360.0)


def sky_case() -> dict[tuple[float, float], tuple[float, float]]:
    """{(σ₀, H): (saturation, hue)}, (0, 0) the clear sky."""
    from forest.render.path.haze import HazeInputs, density_from_visibility

    out = {(0.0, 0.0): saturation_hue(sky_image(None))}
    print(f"sky clear: saturation {out[(0.0, 0.0)][0]:.3f}, hue {out[(0.0, 0.0)][1]:.0f}°")
    for sigma, label in ((0.0009, "demo's haze 0.0009 (V 4.3 km)"), (density_from_visibility(12.0), "V 12 km")):
        for h in (600.0, 300.0, 150.0, 100.0):
            haze = HazeInputs(density=sigma, height=h, sky_distance=30_000.0)
            s, hue = saturation_hue(sky_image(haze))
            out[(sigma, h)] = (s, hue)
            print(
                f"sky {label}, haze_height {h:.0f} m: saturation {s:.3f} ({s / out[(0.0, 0.0)][0]:.0%}), hue {hue:.0f}°"
            )
    return out


def cost_case() -> None:
    """Seconds per frame of the demo with and without a valley fog."""
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    base = load_config(ROOT / "configs" / "demo.toml")
    cases = {
        "haze only": {},
        "haze + valley fog": {"render.valley_fog": {"density": 0.01, "variation": 0.0}},
        "haze + fog banks": {"render.valley_fog": {"density": 0.01, "variation": 8.0}},
    }
    scenes = {}
    for name, over in cases.items():
        scenes[name] = PathScene(
            path_inputs(load_scene(base.with_overrides(over)), width=160, height=90, spp=4), VARIANT
        )
        scenes[name].render()  # warm-up: kernels compiled
    times = dict.fromkeys(cases, np.inf)
    for _ in range(5):  # alternating, so a busy machine slows both alike
        for name, ps in scenes.items():
            t0 = time.perf_counter()
            ps.render()
            times[name] = min(times[name], time.perf_counter() - t0)
    for name, best in times.items():
        print(f"cost demo 160x90x4 ({VARIANT}), {name}: {best:.2f} s (best of 5)")
    print(f"cost valley fog: {times['haze + valley fog'] / times['haze only'] - 1:+.0%}")
    print(
        f"cost fog banks (variation 8 m) against a level top: {times['haze + fog banks'] / times['haze + valley fog']:.2f}x"
    )


def shafts_case(scenes: tuple[str, ...] = ("demo", "ecosystem", "valley"), size: tuple[int, int] = (320, 180)) -> None:
    """Seconds per frame with light shafts against the lit haze, and what they change in the frame's mean
    (examples at ``size``, 8 spp, best of 3 alternating renders)."""
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    for name in scenes:
        base = load_config(ROOT / "configs" / f"{name}.toml")
        runs = {}
        for shafts in (False, True):
            scene = load_scene(base.with_overrides({"render.haze_shafts": shafts}))
            runs[shafts] = PathScene(path_inputs(scene, width=size[0], height=size[1], spp=8), VARIANT)
            runs[shafts].render()  # warm-up: kernels compiled
        times = dict.fromkeys(runs, np.inf)
        images = {}
        for _ in range(3):
            for shafts, ps in runs.items():
                t0 = time.perf_counter()
                out = ps.render()
                times[shafts] = min(times[shafts], time.perf_counter() - t0)
                images[shafts] = np.asarray(out.rgb, np.float64)
        lit, shaded = images[False].mean(), images[True].mean()
        print(
            f"shafts {name} {size[0]}x{size[1]}x8 ({VARIANT}): lit haze {times[False]:.2f} s, shafts "
            f"{times[True]:.2f} s = {times[True] / times[False]:.2f}x; frame mean {lit:.4f} -> {shaded:.4f} "
            f"({shaded / lit - 1:+.1%})"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("sky", "cost", "shafts", "all"), default="all")
    args = ap.parse_args(argv)
    if args.case in ("sky", "all"):
        sky_case()
    if args.case in ("cost", "all"):
        cost_case()
    if args.case in ("shafts", "all"):
        shafts_case()
    return 0


if __name__ == "__main__":
    sys.exit(main())
