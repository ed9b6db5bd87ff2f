"""Wind poses shared by a frame's sub-frames: motion-blurred frames with wind, against a pose per sub-frame.

    .venv/bin/python bench/bench_wind_poses.py [--scenes flythrough,demo] [--size 640x360] [--spp 16] [--runs 2]

Each scene's frame 1 with its own shutter, sub-frames and wind (the fly-through: 5 sub-frames over 1/120 s, 3°
at 0.5 Hz; the demo: 3 over 1/48 s, 1.5° at 0.35 Hz), rendered by ``forest.render.render_scene`` in this process,
twice each way, alternating: the sub-frames sharing the poses the frame loop chooses (``forest.render.loop``,
step 2) against the previous rule, a wind pose and so a scene build per sub-frame (``POSE_PIXELS`` set to 0 for
those runs). Printed per scene: the poses chosen, seconds of scene builds and of rendering, wall and CPU seconds
of the fastest run each way and their ratio, and how far the two pictures are apart — the mean |ΔY| of 16×16-pixel
blocks as a share of the mean — beside the same for the per-sub-frame picture against itself with another render
seed (the noise floor).
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
sys.path.insert(0, str(ROOT / "bench"))

from timing import cpu_seconds, load_line


def blocks(a: np.ndarray, b: np.ndarray, k: int = 16) -> float:
    """Mean |ΔY| of k×k-pixel blocks of two (H, W, 3) linear images, as a share of the second's mean Y."""
    h, w = a.shape[0] // k * k, a.shape[1] // k * k
    y = [(x[:h, :w] @ np.array([0.2126, 0.7152, 0.0722])).reshape(h // k, k, w // k, k).mean((1, 3)) for x in (a, b)]
    return float(np.abs(y[0] - y[1]).mean() / y[1].mean())


def beauty(path: Path) -> np.ndarray:
    """The RGB beauty of a written EXR (its first three channels)."""
    import OpenImageIO as oiio

    return np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT))[..., :3]


def main() -> None:
    import forest.render.loop as loop
    from forest.camera import subframe_times
    from forest.config import load_config
    from forest.render import render_scene
    from forest.scatter import scatter
    from forest.scene import load_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="flythrough,demo")
    ap.add_argument("--size", default="640x360")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--runs", type=int, default=2)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    rule = loop.POSE_PIXELS
    print(f"wind poses: {load_line()} at start; frame 1 at {width}x{height} {args.spp} spp, render_scene in-process")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            sets = {"render.width": width, "render.height": height, "render.spp": args.spp, "render.denoise": False}
            config = load_config(ROOT / "configs" / f"{name}.toml", overrides=sets)
            inst, _ = scatter(config)
            scene = load_scene(config, inst)
            cam = config.camera
            times = subframe_times(1.0, cam.shutter, config.render.subframes)
            shared = sorted(set(loop.pose_times(scene, 1.0, times, width, height)))
            print(
                f"wind poses {name}: {len(scene.instances):,} trees, {len(times)} sub-frames over {cam.shutter:g} of a "
                f"frame at {cam.fps:g} fps, wind {config.wind.strength:g} deg at {config.wind.frequency:g} Hz: "
                f"{len(shared)} pose(s) at frame {', '.join(f'{t:.3f}' for t in shared)}"
            )
            best: dict[str, tuple[float, float, float, float]] = {}
            for _ in range(args.runs):
                for way, pixels in (("shared", rule), ("per sub-frame", 0.0)):
                    loop.POSE_PIXELS = pixels
                    out = Path(tmp) / f"{name}_{way.replace(' ', '_')}.exr"
                    t0, c0 = time.perf_counter(), cpu_seconds()
                    res = render_scene(scene, output=out, variant="llvm_ad_rgb")
                    took = (time.perf_counter() - t0, cpu_seconds() - c0, res.load_seconds, res.render_seconds)
                    if way not in best or took[1] < best[way][1]:
                        best[way] = took
            loop.POSE_PIXELS = 0.0
            other = load_config(ROOT / "configs" / f"{name}.toml", overrides={**sets, "render.seed": 7})
            render_scene(load_scene(other, inst), output=Path(tmp) / f"{name}_seed7.exr", variant="llvm_ad_rgb")
            loop.POSE_PIXELS = rule
            for way, (wall, cpu, load, render) in best.items():
                print(
                    f"wind poses {name} {way:13s}: {wall:6.1f} s wall, {cpu:6.1f} CPU-s (scene builds {load:5.1f} s, "
                    f"rendering {render:5.1f} s)"
                )
            s, e = best["shared"], best["per sub-frame"]
            img = {k: beauty(Path(tmp) / f"{name}_{k}.exr") for k in ("shared", "per_sub-frame", "seed7")}
            print(
                f"wind poses {name}: shared / per sub-frame = {s[1] / e[1]:.2f}x CPU, {s[0] / e[0]:.2f}x wall; picture "
                f"apart by {blocks(img['shared'], img['per_sub-frame']) * 100:.2f} % (16x16 blocks' |dY|), another "
                f"seed by {blocks(img['seed7'], img['per_sub-frame']) * 100:.2f} %; channel means "
                + ", ".join(
                    f"{v:.4f}"
                    for v in img["shared"].reshape(-1, 3).mean(0) / img["per_sub-frame"].reshape(-1, 3).mean(0)
                )
            )
    print(f"wind poses: {load_line()} at end")


if __name__ == "__main__":
    main()
