"""The cost of water on the ground in forest_path (llvm_ad_rgb): the same small scene with and without it.

    .venv/bin/python bench/bench_water.py

A 400 m flat terrain whose left half is water (coverage 1, ripples 2°), 40 boxes standing on it,
sun and a gradient sky, a camera looking across it at 30° below the horizon; 480x270, 64 spp,
max_depth 4.  The two renders alternate (best of 3 each, after one warm-up each that compiles the
kernels), so a busy machine slows both alike.  Figures are printed one per line: wall and CPU seconds
of ``PathScene.render`` with and without water, their ratio, and the mean radiance of each.

Then shallow water (``[ground] water_attenuation``, ``water_depth``): the demo's ground (a lake and a
river) painted with the bed showing through shallow water against the same ground with the bed hidden
(``water_depth = 0``, an attenuation of 1000 per metre); both alternate, best of 3. Renderers read the
same grid either way, so painting is its whole cost. Printed: seconds of ``terrain_albedo``, their ratio,
and the share of water texels whose colour moved by over 10 %.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from timing import best_of


def scene_inputs(water: bool):
    from forest.camera import look_at_matrix
    from forest.instances import InstanceSet
    from forest.lights import sun_vector
    from forest.render.path import Material, PathCamera, PathInputs, SkyLight, SunLight, Surface
    from forest.terrain import grid_terrain

    from render_fixtures import box_mesh

    rng = np.random.default_rng(5)
    boxes = []
    for x, z in rng.uniform(-120.0, 120.0, (40, 2)):
        boxes.append(
            Surface(box_mesh((x - 2.0, 0.0, z - 2.0), (x + 2.0, 8.0, z + 2.0)), Material("surface", (0.1, 0.3, 0.05)))
        )
    colour = np.tile(np.asarray((0.19, 0.14, 0.09), np.float32), (64, 64, 1))
    coverage = np.zeros((64, 64), np.float32)
    coverage[:, :32] = 1.0
    colour[:, :32] = (0.067, 0.074, 0.045)
    camera = PathCamera(look_at_matrix([0.0, 60.0, -200.0], [0.0, 0.0, -40.0], [0.0, 1.0, 0.0]), 60.0, 480, 270)
    return PathInputs(
        instances=InstanceSet.empty(species_names=("box",)),
        species=[None],
        levels=np.zeros(0, np.int64),
        matrices=np.zeros((0, 4, 4)),
        camera=camera,
        terrain=grid_terrain(np.zeros((9, 9)), (400.0, 400.0)),
        terrain_colour=colour,
        terrain_tinted=False,
        surfaces=boxes,
        sun=SunLight(sun_vector(35.0, 200.0), (3.0, 2.9, 2.7)),
        sky=SkyLight("gradient", zenith=(0.1, 0.2, 0.5), horizon=(0.5, 0.5, 0.5)),
        max_depth=4,
        spp=64,
        terrain_water=coverage if water else None,
        water_ripple=2.0,
    )


def main() -> None:
    from forest.render.path import PathScene

    load = os.getloadavg()
    print(f"water: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at start; 480x270 64 spp, max_depth 4")
    scenes = {k: PathScene(scene_inputs(k), "llvm_ad_rgb") for k in (False, True)}
    first, best = best_of({k: (lambda s=s: s.render(seed=1)) for k, s in scenes.items()})
    means = {k: float(img.rgb.mean()) for k, img in first.items()}
    for k, name in ((False, "without water"), (True, "with water (half the ground)")):
        wall, cpu = best[k]
        print(f"water {name:28s}: {wall:6.2f} s wall, {cpu:6.2f} CPU-s, mean {means[k]:.4f}")
    print(f"water cost: {best[True][1] / best[False][1]:.2f}x CPU, {best[True][0] / best[False][0]:.2f}x wall")
    shallow_water()
    load = os.getloadavg()
    print(f"water: load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at end")


def shallow_water() -> None:
    """The demo's ground painted with and without the bed showing through shallow water (module docstring)."""
    from forest.config import load_config
    from forest.ground import terrain_albedo
    from forest.library import open_library
    from forest.scatter import scatter
    from forest.scene import resolve_species
    from forest.terrain import load_terrain

    path = ROOT / "configs" / "demo.toml"
    hidden = {"ground.water_depth": 0.0, "ground.water_attenuation": [1000.0, 1000.0, 1000.0]}
    configs = {True: load_config(path), False: load_config(path, overrides=hidden)}
    inst, _ = scatter(configs[True])
    lib = open_library()
    species = resolve_species(configs[True], list(inst.species_names), lib)
    terrain = load_terrain(configs[True].terrain, configs[True].path)
    first, best = best_of({k: (lambda c=c: terrain_albedo(c, terrain, inst, species)) for k, c in configs.items()})
    shown, hid = first[True], first[False]
    wet = shown.water >= 0.5
    moved = np.abs(shown.rgb[wet] - hid.rgb[wet]).max(axis=1) > 0.1 * np.maximum(hid.rgb[wet].max(axis=1), 1e-6)
    grid = "x".join(str(n) for n in shown.rgb.shape[:2])
    for k, name in ((False, "bed hidden"), (True, "bed through shallow water")):
        wall, cpu = best[k]
        print(f"water shallow: demo ground {grid}, {name:26s}: {wall:6.2f} s wall, {cpu:6.2f} CPU-s")
    print(
        f"water shallow cost: {best[True][1] / best[False][1]:.2f}x CPU, {best[True][0] / best[False][0]:.2f}x wall; "
        f"{moved.mean() * 100:.0f} % of the {wet.sum():,} water texels moved by over 10 %"
    )


if __name__ == "__main__":
    main()
