"""Adaptive sampling (``[render] noise_threshold``) against fixed spp: time and error at the same budget.

    .venv/bin/python bench/bench_adaptive.py                          # configs/demo.toml, 320x180
    .venv/bin/python bench/bench_adaptive.py --spp 16,32,64 --thresholds 0.05,0.1 --ref-spp 256
    .venv/bin/python bench/bench_adaptive.py --set camera.keys.0.target=[0.0,95.0,40.0]   # level: half sky

One scene (the demo's forest, scattered and loaded once, its still at frame 1 without motion blur, so a
sample's cost is the frame's only variable), one forest_path renderer (``llvm_ad_rgb``) whose setting is
switched between runs.  A reference at ``--ref-spp`` is rendered first with another seed; every other
frame is compared with it by the relative RMSE

    rRMSE = √( mean over pixels and channels of (I − R)² / (R + 0.01)² ),

from which the reference's own noise is taken out: the reference's variance is ≈ spp/ref_spp of a run's,
so ``err`` = rRMSE / √(1 + spp/ref_spp) (spp: the mean samples traced per pixel).  For each adaptive run
the fixed-spp curves err = c/√spp and err = c'/√t (Monte Carlo), fitted through the fixed runs, give

* equal samples: the fixed-spp error at the adaptive run's mean traced spp, and the ratio fixed / adaptive
  (the measure that a loaded machine does not disturb);
* equal time: the fixed-spp error at the adaptive run's CPU seconds, and the ratio fixed / adaptive;
* equal error: the fixed-spp CPU seconds that reach the adaptive run's error, and the ratio.

Cost is CPU seconds (user + system, every thread) of the frame, the steadier measure on a shared machine;
each run is repeated ``--repeat`` times and the cheapest kept.  Wall seconds are printed beside it.
"""

from __future__ import annotations

import argparse
import math
import resource
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def load(config: Path, width: int, height: int, trees: int | None, sets: list[str]):
    """The config at ``width``×``height``, still (no shutter), with ``sets`` (``a.b.0.c=<TOML value>``), and
    its scene."""
    import tomlkit

    from forest.config import parse_config
    from forest.scatter import scatter
    from forest.scene import load_scene

    doc = tomlkit.parse(config.read_text())
    doc["render"]["width"], doc["render"]["height"] = width, height  # type: ignore[index]
    doc["camera"]["shutter"] = 0.0  # type: ignore[index]
    if trees is not None:
        doc["scatter"]["count"] = trees  # type: ignore[index]
    for item in sets:
        key, value = item.split("=", 1)
        *path, last = key.split(".")
        node: Any = doc
        for part in path:
            node = node[int(part)] if part.isdigit() else node[part]
        node[int(last) if last.isdigit() else last] = tomlkit.parse(f"v = {value}")["v"]
    cfg = parse_config(tomlkit.dumps(doc), path=config, base_dir=config.parent)
    inst, _ = scatter(cfg)
    return cfg, load_scene(cfg, inst)


def cpu() -> float:
    """CPU seconds of this process so far (user + system, all threads)."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def render(r, spp: int, threshold: float, min_spp: int | None, repeat: int) -> tuple[np.ndarray, float, float, float]:
    """(image, CPU seconds and wall seconds (cheapest of ``repeat``), mean samples per pixel traced)."""
    from forest.render.adaptive import default_min_spp

    r.spp, r.noise_threshold = spp, threshold
    r.min_spp = default_min_spp(spp) if min_spp is None else min(min_spp, spp)
    best, wall, img = math.inf, math.inf, None
    for _ in range(repeat):
        c0, t0 = cpu(), time.perf_counter()
        out = r.frame(1.0)
        best, wall = min(best, cpu() - c0), min(wall, time.perf_counter() - t0)
        img = np.asarray(out.rgb, np.float64)
    assert img is not None
    return img, best, wall, float(r.samples_traced)


def rrmse(img: np.ndarray, ref: np.ndarray) -> float:
    """√(mean((I − R)² / (R + 0.01)²))."""
    return float(np.sqrt(np.mean((img - ref) ** 2 / (ref + 0.01) ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "demo.toml")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--trees", type=int, default=None, help="scatter count (default: the config's)")
    ap.add_argument("--spp", default="16,32,64", help="fixed-spp runs")
    ap.add_argument("--adaptive-spp", type=int, default=64, help="spp of the adaptive runs")
    ap.add_argument("--thresholds", default="0.02,0.05,0.1")
    ap.add_argument("--min-spp", type=int, default=None, help="default: max(16, spp/8)")
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], help="a config value, e.g. camera.keys.0.target=[0,95,40]")
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))

    from forest.render.frame import FrameSize
    from forest.render.render import make_renderer

    t0 = time.perf_counter()
    cfg, scene = load(args.config, width, height, args.trees, args.set)
    r = make_renderer(scene, "llvm_ad_rgb", FrameSize(width, height, args.ref_spp, 1))
    print(
        f"scene: {args.config.name} {width}x{height}, {len(scene.instances):,} trees, max_depth "
        f"{cfg.render.max_depth}, load {time.perf_counter() - t0:.1f} s"
    )
    seed = int(cfg.render.seed)
    object.__setattr__(cfg.render, "seed", seed + 1)  # the reference's noise independent of the runs'
    ref, t_ref, _, _ = render(r, args.ref_spp, 0.0, None, 1)
    object.__setattr__(cfg.render, "seed", seed)
    print(f"reference: {args.ref_spp} spp fixed, {t_ref:.1f} CPU-s")
    render(r, 4, 0.0, None, 1)  # compile the kernels before timing
    render(r, 4, 0.05, 4, 1)

    fixed = []
    for spp in (int(s) for s in args.spp.split(",")):
        img, t, wall, traced = render(r, spp, 0.0, None, args.repeat)
        err = rrmse(img, ref) / math.sqrt(1.0 + traced / args.ref_spp)
        fixed.append((t, traced, err))
        print(f"fixed     spp {spp:4d}: {t:6.2f} CPU-s ({wall:5.2f} s), traced {traced:6.2f} spp, err {err:.4f}")
    # err·√t and err·√spp are constant for Monte Carlo noise: each from the fixed runs (geometric mean)
    c = math.exp(sum(math.log(e * math.sqrt(t)) for t, _, e in fixed) / len(fixed))
    cs = math.exp(sum(math.log(e * math.sqrt(n)) for _, n, e in fixed) / len(fixed))
    print(f"fixed-spp fits: err = {c:.4f} / sqrt(CPU-s) = {cs:.4f} / sqrt(spp)")
    for thr in (float(s) for s in args.thresholds.split(",")):
        img, t, wall, traced = render(r, args.adaptive_spp, thr, args.min_spp, args.repeat)
        err = rrmse(img, ref) / math.sqrt(1.0 + traced / args.ref_spp)
        same_n, same_t, same_e = cs / math.sqrt(traced), c / math.sqrt(t), (c / err) ** 2
        print(
            f"adaptive  spp {args.adaptive_spp:4d} threshold {thr:.3f}: {t:6.2f} CPU-s ({wall:5.2f} s), traced "
            f"{traced:6.2f} spp, err {err:.4f} | equal samples: fixed err {same_n:.4f}, ratio {same_n / err:.2f} | "
            f"equal time: fixed err {same_t:.4f}, ratio {same_t / err:.2f} | "
            f"equal error: fixed {same_e:.2f} CPU-s, ratio {same_e / t:.2f}"
        )


if __name__ == "__main__":
    main()
