"""Building forest_path's Mitsuba scene: Mitsuba's objects built on its thread pool against serially.

    .venv/bin/python bench/bench_scene_load.py [--scenes demo,flythrough,case:100000] [--variant llvm_ad_rgb] [--runs 2]

forest builds the traversal scene (a ``shapegroup`` per prototype, an ``instance`` per tree, merged far
trees, the terrain) with one ``mi.load_dict``; ``case:N`` is the case study of ``bench/bench_render.py`` with N trees
requested, every tree at its highest level (``[lod] auto = false``, as ``bench/bench_cycles.py`` renders it); ``parallel`` says whether Mitsuba builds the objects on its
thread pool (``forest.runtime.PARALLEL_LOAD``, now off). Per example scene, frame 1's
:class:`forest.render.path.PathScene` is built ``--runs`` times each way, alternating, in this process; printed:
the Mitsuba objects in the scene, the seconds of ``load_dict`` and of the whole build (forest's own work
included, wall and CPU) of the fastest run each way and their ratios, and whether one pass of 2 samples renders the same
bytes both ways. The GPU figures (``cuda_ad_rgb`` on an NVIDIA H200: the fly-through's load about 31 s in
parallel, 13.6 s serially, with the same caches) came from ``forest render`` on a lent machine; ``--variant cuda_ad_rgb`` measures them here
where there is a GPU.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from timing import cpu_seconds, load_line


def main() -> None:
    import forest.render.path.geometry as geometry
    import forest.runtime as runtime
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scatter import scatter
    from forest.scene import load_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="demo,flythrough,case:100000")
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=("llvm_ad_rgb", "cuda_ad_rgb"))
    ap.add_argument("--size", default="320x180", help="the image size the levels of detail are chosen for")
    ap.add_argument("--runs", type=int, default=2)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    print(f"scene load: {os.cpu_count()} CPUs, {load_line()} at start; {args.variant}, frame 1 at {width}x{height}")
    runtime.mitsuba(args.variant)
    timed: list[float] = []

    def load_scene_dict(m, entries):  # forest's call, timed
        t0 = time.perf_counter()
        scene = m.load_dict(entries, parallel=runtime.PARALLEL_LOAD)
        timed.append(time.perf_counter() - t0)
        return scene

    geometry.load_scene_dict = load_scene_dict
    default = runtime.PARALLEL_LOAD
    for name in args.scenes.split(","):
        sets = {"render.width": width, "render.height": height, "render.denoise": False}
        if name.startswith("case:"):
            from bench_render import write_scene

            folder = Path(tempfile.mkdtemp(prefix="bench_scene_load_"))
            path = write_scene(folder, count=int(name[5:]), width=width, height=height, spp=2, lod=None, depth=None)
            config = load_config(path, overrides={**sets, "lod": {"auto": False}})
        else:
            config = load_config(ROOT / "configs" / f"{name}.toml", overrides=sets)
        inst, _ = scatter(config)
        inputs = path_inputs(load_scene(config, inst), width=width, height=height, spp=2)
        best: dict[bool, tuple[float, float, float]] = {}
        image: dict[bool, np.ndarray] = {}
        objects = 0
        for _ in range(args.runs):
            for parallel in (True, False):
                runtime.PARALLEL_LOAD = parallel
                t0, c0 = time.perf_counter(), cpu_seconds()
                path = PathScene(inputs, args.variant)
                took = (time.perf_counter() - t0, cpu_seconds() - c0, timed[-1])
                if parallel not in best or took[0] < best[parallel][0]:
                    best[parallel] = took
                if parallel not in image:
                    image[parallel] = np.sum([p.rgb for p in path.passes(spp=2, seed=3)], axis=0)
                objects = len(path.traversal.scene.shapes())
                del path
        runtime.PARALLEL_LOAD = default
        for parallel, (wall, cpu, load) in best.items():
            print(
                f"scene load {name} {'parallel' if parallel else 'serial':8s}: load_dict {load:6.2f} s, whole build "
                f"{wall:6.2f} s wall, {cpu:6.2f} CPU-s"
            )
        s, p = best[False], best[True]
        print(
            f"scene load {name}: {len(inst):,} trees, {objects:,} top-level Mitsuba shapes; serial / parallel = "
            f"{s[2] / p[2]:.2f}x load_dict, {s[0] / p[0]:.2f}x whole build wall, {s[1] / p[1]:.2f}x CPU; one pass the same "
            f"bytes: "
            f"{np.array_equal(image[True], image[False])}"
        )
    print(f"scene load: {load_line()} at end")


if __name__ == "__main__":
    main()
