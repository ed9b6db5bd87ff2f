"""Imaging benchmark: the view transform and the comp-ready EXR at 1920×1080, against today's writers.

    .venv/bin/python bench/bench_imaging.py [--width 1920 --height 1080 --samples 16 --repeat 3]

Printed figures, each the best of ``--repeat`` runs (other work on a shared
machine only ever adds time), with the ratio to the baseline measured in the
same run:

* **view transform**: ``to_display`` (OpenColorIO CPU processor) for agx, filmic
  and standard against the plain clipped sRGB encoding (colour-science's
  ``eotf_inverse_sRGB`` as ``forest.images.write_image`` uses it); then the whole
  PNG write, ``write_display`` against ``write_image``;
* **comp-ready EXR**: ``write_comp_exr`` (RGBA, depth, id, species, two
  Cryptomattes of 3 layers each, camera matrices, colour space) against today's
  ``write_multilayer_exr`` (RGB, depth, id, species), and the bytes each writes;
* **Cryptomatte ranking**: ``forest_mattes`` from one id per pixel (what the
  renderer's id pass gives today) and from ``--samples`` ids per pixel.

The frame is synthetic: a scene-linear HDR beauty, and per-sample tree ids from
a few thousand overlapping discs (crowns) in front of a terrain under a sky.
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

from forest.images import linear_to_srgb, write_image, write_multilayer_exr
from forest.imaging import TreeTable, camera_matrices, forest_mattes, to_display, write_comp_exr, write_display


def best(fn, repeat: int) -> tuple[float, list[float]]:
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return min(runs), runs


def synthetic_frame(width: int, height: int, samples: int, trees: int = 3000):
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([1, 0x1A6E])))
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    beauty = (0.18 * np.exp2(rng.normal(0.0, 1.5, (height, width, 1))) * rng.uniform(0.5, 1.5, 3)).astype(np.float32)
    beauty[: height // 3] = np.array([0.6, 0.75, 1.0], np.float32) * 1.5  # sky
    cx, cy = rng.uniform(0, width, trees), rng.uniform(height / 3, height, trees)
    r = rng.uniform(4, 30, trees)
    order = np.argsort(cy)  # nearer (lower in the frame) crowns drawn last
    ids = np.full((height, width, samples), -1, dtype=np.int64)
    ids[yy.astype(int) >= height // 3] = -2
    jitter = rng.random((samples, 2)).astype(np.float32)
    for k in range(samples):
        px, py = xx + jitter[k, 0], yy + jitter[k, 1]
        plane = ids[..., k]
        for t in order:
            x0, x1 = int(max(cx[t] - r[t], 0)), int(min(cx[t] + r[t] + 1, width))
            y0, y1 = int(max(cy[t] - r[t], 0)), int(min(cy[t] + r[t] + 1, height))
            sub = (px[y0:y1, x0:x1] - cx[t]) ** 2 + (py[y0:y1, x0:x1] - cy[t]) ** 2 < r[t] ** 2
            plane[y0:y1, x0:x1][sub] = t
    table = TreeTable(
        np.arange(trees), rng.integers(0, 4, trees), ["broadleaf", "conifer", "palm", "shrub"], {-2: "terrain"}
    )
    return beauty, ids, table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    w, h, n = args.width, args.height, args.repeat
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; best of {n} runs; {w}x{h}")
    t0 = time.perf_counter()
    beauty, ids, table = synthetic_frame(w, h, args.samples)
    print(f"synthetic frame ({args.samples} ids per pixel) built in {time.perf_counter() - t0:.1f} s")

    base, _ = best(lambda: linear_to_srgb(beauty), n)
    print(f"view: clipped sRGB (colour-science)   {base * 1000:7.1f} ms   1.00x  (baseline)")
    for view in ("standard", "filmic", "agx"):
        t, _ = best(lambda view=view: to_display(beauty, view, 1.0), n)
        print(f"view: to_display {view:<8} (OCIO)     {t * 1000:7.1f} ms   {t / base:.2f}x")
    agx, _ = best(lambda: to_display(beauty, "agx", 1.0), n)
    t, _ = best(lambda: to_display(beauty, "agx", 1.0, "punchy"), n)
    print(f"look: agx + punchy (OCIO look)        {t * 1000:7.1f} ms   {t / agx:.2f}x the agx view alone")

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        base_png, _ = best(lambda: write_image(d / "base.png", beauty), n)
        print(f"PNG:  write_image (clipped sRGB)      {base_png * 1000:7.1f} ms   1.00x  (baseline)")
        t, _ = best(lambda: write_display(d / "agx.png", beauty, view="agx"), n)
        print(f"PNG:  write_display agx 8-bit         {t * 1000:7.1f} ms   {t / base_png:.2f}x")
        t, _ = best(lambda: write_display(d / "agx16.png", beauty, view="agx", bits=16), n)
        print(f"PNG:  write_display agx 16-bit        {t * 1000:7.1f} ms   {t / base_png:.2f}x")

        centre = ids[..., 0]
        depth = np.where(centre == -1, 1e5, 100.0).astype(np.float32)
        species = table.species_of(centre)
        base_exr, _ = best(
            lambda: write_multilayer_exr(
                d / "base.exr", {"": beauty, "depth": depth, "id": centre, "species": species}, attributes={}
            ),
            n,
        )
        size_base = (d / "base.exr").stat().st_size
        print(f"EXR:  write_multilayer_exr (today)    {base_exr * 1000:7.1f} ms   1.00x  {size_base / 2**20:6.1f} MiB")

        t1, _ = best(lambda: forest_mattes(centre, None, table), n)
        print(f"Cryptomatte ranking, 1 id per pixel   {t1 * 1000:7.1f} ms")
        tn, _ = best(lambda: forest_mattes(ids, None, table), max(1, n - 1))
        print(f"Cryptomatte ranking, {args.samples} ids per pixel  {tn * 1000:7.1f} ms")
        mattes = forest_mattes(ids, None, table)
        cam = camera_matrices([0, 50, -400], [0, 20, 0], [0, 1, 0], 40.0, w, h)
        alpha = (ids != -1).mean(axis=2).astype(np.float32)
        t, _ = best(
            lambda: write_comp_exr(
                d / "comp.exr",
                beauty,
                alpha=alpha,
                depth=depth,
                tree_id=centre,
                species=species,
                species_names=table.species_names,
                mattes=mattes,
                camera=cam,
            ),
            n,
        )
        size = (d / "comp.exr").stat().st_size
        print(
            f"EXR:  write_comp_exr (+A, 2x3 crypto) {t * 1000:7.1f} ms   {t / base_exr:.2f}x  {size / 2**20:6.1f} MiB"
        )
        print(f"      manifests: {len(mattes[0].manifest)} trees, {len(mattes[1].manifest)} species")
    print(f"load average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
