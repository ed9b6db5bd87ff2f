"""Comp AOVs: what the light groups cost forest_path's kernel, how exactly they sum, and the docs' picture.

    .venv/bin/python bench/bench_aovs.py                                # cost and sum error, demo scene
    .venv/bin/python bench/bench_aovs.py --picture docs/images/lightgroups.png

The cost: the demo scene (``configs/demo.toml``, ``--count`` trees, frame 30 of its fly-through)
traced by :meth:`forest.render.path.PathScene.passes` at ``--size`` × ``--spp``, in process CPU
seconds, alternating runs without and with the light-group split (``groups=True``), after one
warm-up of each kernel.  The sum error: max over pixels of |Σ_g group_g − beauty| / beauty.

The picture: beauty | sun | sky | haze of the same frame, each through the PNG's view transform
(``agx``) at the same exposure, so the panels' brightness compares directly.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=3000)
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--frame", type=float, default=30.0)
    ap.add_argument("--picture", type=Path, default=None)
    args = ap.parse_args()

    from forest.config import parse_config
    from forest.imaging.view import quantise, to_display
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_camera, path_inputs
    from forest.scatter import scatter
    from forest.scene import load_scene

    w, h = (int(v) for v in args.size.split("x"))
    config = ROOT / "configs" / "demo.toml"
    text = config.read_text().replace("count = 20000", f"count = {args.count}")
    cfg = parse_config(text, path=config, base_dir=config.parent)
    inst, _ = scatter(cfg)
    scene = load_scene(cfg, inst)
    path = PathScene(path_inputs(scene, frame=args.frame, width=w, height=h, spp=args.spp), "llvm_ad_rgb")
    camera = path_camera(cfg, args.frame, w, h)

    def run(groups: bool) -> tuple[float, np.ndarray, dict[str, np.ndarray]]:
        t0 = time.process_time()
        rgb, split, n = np.zeros((h * w, 3)), {}, 0
        for p in path.passes(camera, spp=args.spp, seed=1, aux=True, groups=groups):
            rgb += p.rgb
            n += p.spp
            for g, v in (p.groups or {}).items():
                split[g] = split.get(g, 0.0) + v
        return time.process_time() - t0, rgb / n, {g: v / n for g, v in split.items()}

    run(False)
    run(True)
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.runs):
        for groups in (False, True):
            seconds, rgb, split = run(groups)
            times[groups].append(seconds)
    total = sum(split.values())
    err = np.abs(total - rgb) / np.maximum(np.abs(rgb), 1e-6)
    print(f"{len(inst)} trees, {w}x{h} x {args.spp} spp, groups {sorted(split)}")
    print("kernel CPU-s without groups:", ", ".join(f"{t:.2f}" for t in times[False]))
    print("kernel CPU-s with groups:   ", ", ".join(f"{t:.2f}" for t in times[True]))
    print(f"sum of groups vs beauty: max relative error {err.max():.2e}, mean {err.mean():.2e}")
    for g, v in split.items():
        print(f"  {g}: mean {v.mean(axis=0).round(4).tolist()} ({v.sum() / rgb.sum():.1%} of the beauty)")
    if args.picture is not None:
        from PIL import Image, ImageDraw

        panels = [("beauty", rgb)] + [(g, split[g]) for g in ("sun", "sky", "haze") if g in split]
        tiles = []
        for name, img in panels:
            d = quantise(to_display(img.reshape(h, w, 3).astype(np.float32), view=cfg.render.view))
            tile = Image.fromarray(np.asarray(d, np.uint8))
            ImageDraw.Draw(tile).text((6, 4), name, fill=(255, 255, 255))
            tiles.append(tile)
        sheet = Image.new("RGB", (w * len(tiles) + 4 * (len(tiles) - 1), h), (0, 0, 0))
        for k, tile in enumerate(tiles):
            sheet.paste(tile, (k * (w + 4), 0))
        args.picture.parent.mkdir(parents=True, exist_ok=True)
        sheet.save(args.picture, optimize=True)
        print("wrote", args.picture)


if __name__ == "__main__":
    main()
