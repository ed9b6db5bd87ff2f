"""forest_path (llvm_ad_rgb) against the scalar_rgb renderer: speed, scale, memory, noise, textures.

    .venv/bin/python bench/bench_forest_path.py                    # every case
    .venv/bin/python bench/bench_forest_path.py --case scale --scale 0.2

Cases (each measurement in its own process, so peak memory is its own; the
two renderers alternate so a busy machine slows both alike):

* ``scale`` — 1 000, 10 000, 50 000 and 130 000 trees (broadleaf and conifer
  over a procedural terrain growing with the count, constant density, levels of
  detail by distance), one frame at the same size, samples and path depth:
  forest_path (build + beauty + depth/id/species layers) against
  ``forest.render.render_image`` in scalar_rgb (scene + beauty + its id/depth
  pass); wall and CPU seconds, peak RSS, the ratio, and the time per tree.  At
  10 000 trees also scalar_rgb with ``[render] alpha_shadows`` (``volpath``),
  which renders the cut-out shadows forest_path always renders.
* ``noise`` — noise per sample: each renderer twice with two seeds at equal
  samples; σ = std(a − b)/√2 over the image; forest_path with Mitsuba's
  ``multijitter``, ``independent`` and ``ldsampler`` samplers against
  scalar_rgb's independent sampler, and the efficiency 1/(σ²·t).
* ``memory`` — resident memory per instanced tree in llvm (every tree an
  instance of its low level of detail, two forest sizes, the difference).
* ``million`` — 1 000 000 trees: how many stay instances after the far level
  is merged, and a small frame if it fits.
* ``atlas`` — the texture lookup: one RGBA atlas against one masked lookup per
  texture, in llvm.

Figures are printed one per line.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENE = """
name = "bench"
seed = 5
[terrain]
procedural = {{ size = {size}, height = 120.0, resolution = 257 }}
[scatter]
count = {count}
[[species]]
model = "broadleaf"
percent = 60
scale = [0.8, 1.3]
[[species]]
model = "conifer"
percent = 40
scale = [0.9, 1.4]
[camera]
position = [0.0, 260.0, {camz}]
target = [0.0, 60.0, {targetz}]
fov = 55.0
[lights]
sun = {{ elevation = 35.0, azimuth = 140.0, irradiance = 3.2, colour = [1.0, 0.93, 0.82] }}
sky = {{ radiance = 0.45, colour = [0.55, 0.7, 1.0] }}
[render]
width = {width}
height = {height}
spp = {spp}
max_depth = {depth}
seed = {seed}
alpha_shadows = {alpha_shadows}
[lod]
distances = [150.0, 600.0, 1800.0]
"""


def write_scene(
    folder: Path, *, count: int, width: int, height: int, spp: int, depth: int, seed: int = 0, alpha_shadows=False
) -> Path:
    size = float(np.sqrt(count / 130_000.0) * 4000.0)  # ~8 trees per 1000 m² at every count
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"bench_{count}_{seed}{'_alpha' if alpha_shadows else ''}.toml"
    path.write_text(
        SCENE.format(
            size=size, count=count, camz=-0.45 * size, targetz=-0.1 * size, width=width, height=height, spp=spp,
            depth=depth, seed=seed, alpha_shadows=str(bool(alpha_shadows)).lower(),
        )
    )  # fmt: skip
    return path


def cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def peak_gb() -> float:
    """Peak resident memory of this process, GiB (ru_maxrss is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def rss_now() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown CPU"


def load_average() -> str:
    try:
        return " / ".join(f"{v:.1f}" for v in os.getloadavg())
    except OSError:
        return "?"


# -- workers (run in a child process) ------------------------------------------------------


def _scene_inputs(config_path: str):
    from forest.config import load_config
    from forest.library import open_library
    from forest.scatter import scatter

    cfg = load_config(config_path)
    inst, _ = scatter(cfg)
    return cfg, inst, open_library()


def worker_path(args) -> dict:
    """forest_path: build the scene, render the beauty and the layers; times, memory, image statistics."""
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    cfg, inst, lib = _scene_inputs(args.config)
    c0, t0 = cpu_s(), time.perf_counter()
    inputs = path_inputs(load_scene(cfg, inst, library=lib))
    inputs.sampler = args.sampler
    scene = PathScene(inputs, "llvm_ad_rgb")
    t_build = time.perf_counter() - t0
    t1 = time.perf_counter()
    img = scene.render()
    t_beauty = time.perf_counter() - t1
    t2 = time.perf_counter()
    scene.layers()
    t_layers = time.perf_counter() - t2
    if args.save:
        np.save(args.save, img.rgb)
    st = scene.stats
    return {
        "trees": len(inst),
        "instances": st.instances,
        "flattened": st.flattened_trees,
        "build_s": t_build,
        "beauty_s": t_beauty,
        "layers_s": t_layers,
        "frame_s": time.perf_counter() - t0,
        "cpu_s": cpu_s() - c0,
        "peak_gb": peak_gb(),
        "mean": float(img.rgb.mean()),
        "spp": img.spp,
    }


def worker_scalar(args) -> dict:
    """Today's scalar_rgb renderer (``render_image``: scene, beauty, id/depth pass) on the same config."""
    from forest.render.render import render_image
    from forest.scene import load_scene

    cfg, inst, lib = _scene_inputs(args.config)
    rc = cfg.render
    c0, t0 = cpu_s(), time.perf_counter()
    img = render_image(
        load_scene(cfg, inst, library=lib), width=rc.width, height=rc.height, spp=rc.spp, variant="scalar_rgb"
    )
    if args.save:
        np.save(args.save, np.asarray(img, np.float32))
    return {
        "trees": len(inst),
        "frame_s": time.perf_counter() - t0,
        "cpu_s": cpu_s() - c0,
        "peak_gb": peak_gb(),
        "mean": float(np.mean(img)),
    }


def worker_memory(args) -> dict:
    """RSS added by a forest_path scene whose trees are all instances (low level of detail)."""
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    cfg, inst, lib = _scene_inputs(args.config)
    inputs = path_inputs(load_scene(cfg, inst, library=lib), width=32, height=18, spp=1)
    inputs.levels = np.full(len(inst), 2, np.int64)
    inputs.flatten_triangles = 0
    from forest.runtime import mitsuba

    mitsuba("llvm_ad_rgb")
    base = rss_now()
    scene = PathScene(inputs, "llvm_ad_rgb")
    return {"trees": len(inst), "instances": scene.stats.instances, "added": rss_now() - base}


def worker_million(args) -> dict:
    """1 M trees: the instance count after the far level is merged; a small frame when it fits."""
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    t0 = time.perf_counter()
    cfg, inst, lib = _scene_inputs(args.config)
    t_scatter = time.perf_counter() - t0
    inputs = path_inputs(load_scene(cfg, inst, library=lib))
    counts = np.bincount(inputs.levels, minlength=4)
    t1 = time.perf_counter()
    scene = PathScene(inputs, "llvm_ad_rgb")
    t_build = time.perf_counter() - t1
    t2 = time.perf_counter()
    img = scene.render()
    t_render = time.perf_counter() - t2
    st = scene.stats
    return {
        "trees": len(inst),
        "levels": counts.tolist(),
        "instances": st.instances,
        "flattened": st.flattened_trees,
        "flat_triangles": st.flattened_triangles,
        "scatter_s": t_scatter,
        "build_s": t_build,
        "render_s": t_render,
        "peak_gb": peak_gb(),
        "mean": float(img.rgb.mean()),
    }


def worker_atlas(_args) -> dict:
    """Texture lookups in llvm: one RGBA atlas against one masked lookup per texture."""
    import drjit as dr

    from forest.render.path.materials import pack_atlas
    from forest.runtime import mitsuba

    mi = mitsuba("llvm_ad_rgb")
    rng = np.random.default_rng(0)
    shapes = [(256, 256)] * 6 + [(128, 384)] * 3 + [(64, 64)] * 4
    images = [rng.uniform(0, 1, (h, w, 4)).astype(np.float32) for h, w in shapes]
    atlas = pack_atlas(images)
    n = 1 << 21
    tex_id = mi.UInt32(rng.integers(0, len(images), n).astype(np.uint32))
    uv = mi.Point2f(
        mi.Float(rng.uniform(0, 4, n).astype(np.float32)), mi.Float(rng.uniform(0, 4, n).astype(np.float32))
    )
    dr.eval(tex_id, uv)
    big = mi.Texture2f(mi.TensorXf(atlas.image), filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)
    rects = mi.Float(atlas.rects.ravel())
    singles = [
        mi.Texture2f(mi.TensorXf(im), filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Repeat) for im in images
    ]

    def via_atlas(k):
        r = dr.gather(mi.Vector4f, rects, tex_id)
        f = uv + k * 1e-7
        f = f - dr.floor(f)
        return big.eval(mi.Point2f(dr.fma(f.x, r.z, r.x), dr.fma(f.y, r.w, r.y)))

    def via_masks(k):
        out = [mi.Float(0.0)] * 4
        p = uv + k * 1e-7
        for t, tex in enumerate(singles):
            m = tex_id == t
            v = tex.eval(p, active=m)
            out = [dr.select(m, v[c], out[c]) for c in range(4)]
        return out

    times = {}
    for name, fn in (("atlas", via_atlas), ("masked", via_masks)):
        best = 1e9
        for k in range(4):
            t0 = time.perf_counter()
            v = fn(k)
            dr.eval(*v)
            dr.sync_thread()  # kernels run asynchronously: wait for this one
            best = min(best, time.perf_counter() - t0) if k else best  # k = 0 compiles
        times[name] = best
    return {"lanes": n, "textures": len(images), **times}


WORKERS = {
    "path": worker_path,
    "scalar": worker_scalar,
    "memory": worker_memory,
    "million": worker_million,
    "atlas": worker_atlas,
}


def run_worker(kind: str, **kw) -> dict:
    cmd = [sys.executable, __file__, "--worker", kind] + [f"--{k.replace('_', '-')}={v}" for k, v in kw.items()]
    r = subprocess.run(cmd, capture_output=True, text=True)
    # The last JSON object on stdout (Mitsuba may print coloured warnings on the same stream).
    lines = [line[line.index('{"') :] for line in r.stdout.strip().splitlines() if '{"' in line]
    if r.returncode != 0 or not lines:
        raise SystemExit(f"bench worker {kind} failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    return json.loads(lines[-1])


# -- cases --------------------------------------------------------------------------------------


def case_scale(tmp: Path, scale: float, width: int, height: int, spp: int, depth: int) -> None:
    print(f"forest_path scale: {cpu_model()}, {os.cpu_count()} cores; load average {load_average()} at start")
    per_tree = {}
    for count in (1_000, 10_000, 50_000, 130_000):
        n = max(200, int(count * scale))
        cfg = write_scene(tmp, count=n, width=width, height=height, spp=spp, depth=depth)
        p = run_worker("path", config=cfg, sampler="multijitter", save="")
        s = run_worker("scalar", config=cfg, save="")
        per_tree[count] = (p["build_s"] / p["trees"], p["frame_s"] / p["trees"])
        print(
            f"forest_path scale {p['trees']:,} trees ({p['instances']:,} instances, {p['flattened']:,} merged far), "
            f"{width}x{height} {spp} spp, max_depth {depth}: llvm {p['frame_s']:.1f} s wall / {p['cpu_s']:.1f} CPU-s "
            f"(build {p['build_s']:.1f} s, beauty {p['beauty_s']:.1f} s, layers {p['layers_s']:.2f} s), peak "
            f"{p['peak_gb']:.2f} GiB | scalar_rgb {s['frame_s']:.1f} s wall / {s['cpu_s']:.1f} CPU-s, peak "
            f"{s['peak_gb']:.2f} GiB | scalar/llvm time ratio {s['frame_s'] / p['frame_s']:.2f} wall, "
            f"{s['cpu_s'] / p['cpu_s']:.2f} CPU (goal ≥ 2)"
        )
        if count == 10_000:
            # The scalar renderer with the same cut-out shadows: [render] alpha_shadows (volpath).
            cfg_a = write_scene(tmp, count=n, width=width, height=height, spp=spp, depth=depth, alpha_shadows=True)
            a = run_worker("scalar", config=cfg_a, save="")
            print(
                f"forest_path scale {p['trees']:,} trees: scalar_rgb with alpha_shadows (volpath, the cut-out "
                f"shadows forest_path renders) {a['frame_s']:.1f} s wall / {a['cpu_s']:.1f} CPU-s: ratio to llvm "
                f"{a['frame_s'] / p['frame_s']:.2f} wall, {a['cpu_s'] / p['cpu_s']:.2f} CPU"
            )
    if 10_000 in per_tree and 130_000 in per_tree:
        (b10, f10), (b130, f130) = per_tree[10_000], per_tree[130_000]
        print(
            f"forest_path scale: per tree, 10k → 130k trees: scene build {b10 * 1e6:.0f} → {b130 * 1e6:.0f} µs "
            f"(ratio {b130 / b10:.2f}), whole frame {f10 * 1e6:.0f} → {f130 * 1e6:.0f} µs (ratio {f130 / f10:.2f}); "
            f"flat within 2×: {'yes' if max(b130 / b10, f130 / f10) <= 2 else 'no'}"
        )
    print(f"forest_path scale: load average {load_average()} at end")


def case_noise(tmp: Path, scale: float, width: int, height: int, spp: int, depth: int) -> None:
    n = max(200, int(10_000 * scale))
    runs = {}
    for sampler in ("multijitter", "independent", "ldsampler", "scalar"):
        imgs, secs = [], []
        for seed in (1, 2):
            cfg = write_scene(tmp, count=n, width=width, height=height, spp=spp, depth=depth, seed=seed)
            out = tmp / f"noise_{sampler}_{seed}.npy"
            if sampler == "scalar":
                r = run_worker("scalar", config=cfg, save=out)
            else:
                r = run_worker("path", config=cfg, sampler=sampler, save=out)
            imgs.append(np.load(out).astype(np.float64))
            secs.append(r["cpu_s"])
        sigma = float(np.std(imgs[0] - imgs[1]) / np.sqrt(2))
        mean = float((imgs[0] + imgs[1]).mean() / 2)
        runs[sampler] = (sigma, mean, float(np.mean(secs)))
    s_sig, s_mean, s_t = runs["scalar"]
    for name in ("multijitter", "independent", "ldsampler"):
        sig, mean, t = runs[name]
        print(
            f"forest_path noise {n:,} trees {width}x{height} {spp} spp: {name} σ {sig:.5f} (σ/mean {sig / mean:.3f}) "
            f"vs scalar_rgb independent σ {s_sig:.5f} (σ/mean {s_sig / s_mean:.3f}): σ ratio {sig / s_sig:.2f}; "
            f"efficiency 1/(σ²·CPU-s) ratio llvm/scalar {(s_sig**2 * s_t) / (sig**2 * t):.2f}"
        )


def case_memory(tmp: Path, scale: float) -> None:
    a, b = max(200, int(5_000 * scale)), max(400, int(20_000 * scale))
    ra = run_worker("memory", config=write_scene(tmp, count=a, width=32, height=18, spp=1, depth=2))
    rb = run_worker("memory", config=write_scene(tmp, count=b, width=32, height=18, spp=1, depth=2))
    per = (rb["added"] - ra["added"]) / max(rb["instances"] - ra["instances"], 1)
    print(
        f"forest_path memory: {ra['instances']:,} instances +{ra['added'] / 2**20:.0f} MB, {rb['instances']:,} "
        f"instances +{rb['added'] / 2**20:.0f} MB: {per / 1024:.1f} KB per instanced tree in llvm"
    )


def case_million(tmp: Path, scale: float) -> None:
    n = max(1000, int(1_000_000 * scale))
    cfg = write_scene(tmp, count=n, width=320, height=180, spp=4, depth=3)
    r = run_worker("million", config=cfg)
    lv = r["levels"]
    print(
        f"forest_path million: {r['trees']:,} trees (levels high/medium/low/far {lv}): {r['instances']:,} instances, "
        f"{r['flattened']:,} far trees merged into {r['flat_triangles']:,} triangles; scatter {r['scatter_s']:.1f} s, "
        f"build {r['build_s']:.1f} s, 320x180 4 spp {r['render_s']:.1f} s, peak {r['peak_gb']:.2f} GiB (≤ 6 GB)"
    )


def case_atlas() -> None:
    r = run_worker("atlas")
    print(
        f"forest_path atlas: {r['lanes']:,} bilinear RGBA lookups over {r['textures']} textures in llvm: one atlas "
        f"{r['atlas'] * 1e3:.0f} ms, masked per texture {r['masked'] * 1e3:.0f} ms — atlas "
        f"{r['masked'] / r['atlas']:.1f}× faster"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="all", help="scale, noise, memory, million, atlas or all")
    ap.add_argument("--scale", type=float, default=1.0, help="fraction of the tree counts")
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=270)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=3)
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--config", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--sampler", default="multijitter", help=argparse.SUPPRESS)
    ap.add_argument("--save", default="", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(WORKERS[args.worker](args)))
        return
    cases = ["scale", "noise", "memory", "million", "atlas"] if args.case == "all" else args.case.split(",")
    with tempfile.TemporaryDirectory(prefix="forest-bench-path-") as d:
        tmp = Path(d)
        for c in cases:
            if c == "scale":
                case_scale(tmp / c, args.scale, args.width, args.height, args.spp, args.max_depth)
            elif c == "noise":
                case_noise(tmp / c, args.scale, args.width // 2, args.height // 2, args.spp, args.max_depth)
            elif c == "memory":
                (tmp / c).mkdir()
                case_memory(tmp / c, args.scale)
            elif c == "million":
                (tmp / c).mkdir()
                case_million(tmp / c, args.scale)
            elif c == "atlas":
                case_atlas()
            else:
                raise SystemExit(f"unknown case {c!r}")
    print("forest_path note: no GPU on this machine; cuda_ad_rgb not measured (the code has no llvm-only construct)")


if __name__ == "__main__":
    main()
