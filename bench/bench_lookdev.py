"""Look-dev benchmark: synthetic round trip, unaligned photo, proxy design.

    .venv/bin/python bench/bench_lookdev.py [--iterations 200] [--spp 8] [--skip-proxy]

1. **Round trip** (aligned): a reference is rendered from a hidden 8×8
   colour map, sun and sky; ``forest.lookdev.match`` starts from a different
   guess and must recover them.  Printed: colour-map mean and max CIEDE2000 over
   the cells the camera sees, each light value's relative error, wall time.
   Targets: mean ≤ 0.5, max ≤ 2, lights within 2 %, ≤ 60 s on 2 cores.
2. **Unaligned photo** (statistics): the reference is a *different* random
   forest (another seed) seen from a moved camera, with a hidden global tint
   and sky; the fit is the tint and the sky.  Targets: tint within 3 CIEDE2000,
   sky within 5 %.
3. **Proxy design**: the same low-LOD forest rendered in ``llvm_ad_rgb`` as
   ``instance`` shapes and as merged meshes (the proxy), seconds per
   forward+backward iteration, and the ratio.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENE = """
seed = {seed}
[terrain.procedural]
size = 80.0
height = 5.0
resolution = 32
seed = 4
[scatter]
count = {count}
[[species]]
model = "broadleaf"
percent = 60
scale = [0.5, 0.8]
[[species]]
model = "conifer"
percent = 40
scale = [0.4, 0.7]
[camera]
position = {position}
target = {target}
fov = 60
[lights.sun]
elevation = 30
azimuth = 140
irradiance = {sun}
colour = {sun_colour}
[lights.sky]
radiance = {sky}
colour = {sky_colour}
[render]
width = 320
height = 240
spp = 16
max_depth = 4
"""


def scene(
    folder: Path,
    name: str,
    *,
    seed=3,
    count=160,
    position=(0.0, 95.0, -32.0),
    target=(0.0, 0.0, 3.0),
    sun=3.0,
    sun_colour=(1.0, 0.95, 0.85),
    sky=0.4,
    sky_colour=(0.6, 0.75, 1.0),
    extra="",
) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name

    def fmt(v):
        return "[" + ", ".join(f"{x:g}" for x in v) + "]"

    p.write_text(
        textwrap.dedent(
            SCENE.format(
                seed=seed,
                count=count,
                position=fmt(position),
                target=fmt(target),
                sun=sun,
                sun_colour=fmt(sun_colour),
                sky=sky,
                sky_colour=fmt(sky_colour),
            )
        )
        + extra
    )
    return p


def round_trip(tmp: Path, iterations: int, spp: int) -> dict:
    from forest.config import load_config
    from forest.lookdev import match
    from forest.lookdev.colour import delta_e2000
    from forest.lookdev.forest_proxy import build_proxy
    from forest.lookdev.state import state_from_config
    from forest.scene import load_scene

    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([2026, 6])))
    hidden = rng.uniform(0.3, 1.0, (8, 8, 3))
    true_cfg = load_config(
        scene(tmp / "truth", "scene.toml", sun=3.4, sun_colour=(1.0, 0.92, 0.8), sky=0.33, sky_colour=(0.55, 0.72, 1.0))
    )
    start_cfg = load_config(scene(tmp / "start", "scene.toml"))
    true_scene = load_scene(true_cfg)
    inst = true_scene.instances
    truth = state_from_config(true_cfg, hidden)
    res = 64
    w, h = res, round(res * 240 / 320)
    proxy = build_proxy(true_scene, width=w, height=h, grid_shape=(8, 8), variant="llvm_ad_rgb", state=truth)
    proxy.set_state(truth)
    t = time.perf_counter()
    ref = proxy.render_numpy(256, 777, passes=16)
    t_ref = time.perf_counter() - t
    start = state_from_config(start_cfg, np.full((8, 8, 3), 0.7))
    t, c = time.perf_counter(), time.process_time()
    r = match(
        load_scene(start_cfg, inst),
        ref,
        tmp / "out_rt",
        iterations=iterations,
        spp=spp,
        resolution=res,
        grid=8,
        start=start,
    )
    seconds, cpu = time.perf_counter() - t, time.process_time() - c
    fit = r.result
    de = delta_e2000(fit.grid.reshape(-1, 3), hidden.reshape(-1, 3))
    lights = {
        "sun irradiance": fit.sun_irradiance / truth.sun_irradiance - 1,
        "sky radiance": fit.sky_radiance / truth.sky_radiance - 1,
    }
    for i, ch in enumerate("rgb"):
        lights[f"sun colour {ch}"] = fit.sun_colour[i] / truth.sun_colour[i] - 1
        lights[f"sky colour {ch}"] = fit.sky_colour[i] / truth.sky_colour[i] - 1
    return {
        "seconds": seconds,
        "cpu_seconds": cpu,
        "reference_seconds": t_ref,
        "de_mean": float(de.mean()),
        "de_max": float(de.max()),
        "lights": lights,
        "figures": r.figures,
        "size": (w, h),
    }


def unaligned(tmp: Path, iterations: int, spp: int) -> dict:
    from forest.config import load_config
    from forest.images import write_image
    from forest.lookdev import match
    from forest.lookdev.colour import delta_e2000
    from forest.render import render_scene
    from forest.scene import load_scene

    tint = np.array([0.78, 1.0, 0.62])
    base = np.full((8, 8, 3), 0.8)
    (tmp / "maps").mkdir(parents=True, exist_ok=True)
    write_image(tmp / "maps" / "base.exr", base.astype(np.float32), half=False)
    write_image(tmp / "maps" / "tinted.exr", (base * tint).astype(np.float32), half=False)
    ref_cfg = load_config(
        scene(
            tmp / "photo",
            "scene.toml",
            seed=99,
            count=400,
            position=(8.0, 26.0, -58.0),
            target=(4.0, 2.0, 10.0),
            sky=0.52,
            extra='[maps]\ncolour = "../maps/tinted.exr"\n',
        )
    )
    render_scene(load_scene(ref_cfg), output=tmp / "photo" / "photo.exr", variant="scalar_rgb")
    cfg = load_config(
        scene(
            tmp / "scene",
            "scene.toml",
            count=400,
            position=(0.0, 26.0, -58.0),
            target=(0.0, 2.0, 10.0),
            extra='[maps]\ncolour = "../maps/base.exr"\n',
        )
    )
    t = time.perf_counter()
    r = match(
        load_scene(cfg),
        tmp / "photo" / "photo.exr",
        tmp / "out_un",
        iterations=iterations,
        spp=spp,
        resolution=64,
        grid=8,
        mode="statistics",
        params="colour_map,sky",
    )
    seconds = time.perf_counter() - t
    fitted_tint = r.result.tint
    from forest.lookdev.state import split_colour

    sky_true_l, _ = split_colour(0.52, (0.6, 0.75, 1.0))
    return {
        "seconds": seconds,
        "tint": fitted_tint,
        "tint_de": float(delta_e2000(fitted_tint * 0.8, tint * 0.8)),
        "start_tint_de": float(delta_e2000(np.ones(3) * 0.8, tint * 0.8)),
        "sky": r.result.sky_radiance / sky_true_l - 1,
        "start_sky": r.start.sky_radiance / sky_true_l - 1,
        "figures": r.figures,
    }


def proxy_design(tmp: Path) -> dict:
    """Seconds per forward+backward iteration: N instances vs the merged proxy, same trees."""
    from forest.runtime import mitsuba

    mi = mitsuba("llvm_ad_rgb")
    import drjit as dr

    from forest.config import load_config
    from forest.library import open_library
    from forest.lookdev.forest_proxy import build_proxy
    from forest.lookdev.state import state_from_config
    from forest.render.instancing import tree_matrices
    from forest.render.scene import colour_grid_texture, emitter_dicts, sensor_dict
    from forest.scene import load_scene

    out = {}
    for count in (100, 400):
        cfg = load_config(scene(tmp / f"pd{count}", "scene.toml", count=count))
        sc = load_scene(cfg)
        inst, terrain = sc.instances, sc.terrain
        st = state_from_config(cfg, np.ones((8, 8, 3)))
        t = time.perf_counter()
        proxy = build_proxy(sc, width=64, height=48, grid_shape=(8, 8), variant="llvm_ad_rgb", state=st)
        build = time.perf_counter() - t

        def step(p):
            img = mi.render(p.scene, p.params, spp=4, seed=1, spp_grad=4)
            dr.backward(dr.mean(img.array))

        proxy.params.keep([t.key for t in proxy.grid_targets])
        dr.enable_grad(proxy.params[proxy.grid_targets[0].key])
        proxy.params.update()
        step(proxy)
        t = time.perf_counter()
        for _ in range(3):
            step(proxy)
        merged = (time.perf_counter() - t) / 3
        # The same trees as instances of per-species low-LOD shapegroups.
        lib = open_library()
        grid = colour_grid_texture(np.ones((8, 8, 3)), terrain.extent, terrain.height_range, "llvm_ad_rgb")
        d = {
            "type": "scene",
            "integrator": {"type": "prb", "max_depth": 4},
            "sensor": sensor_dict(cfg, 1.0, 64, 48, 4, "llvm_ad_rgb", rfilter="box"),
            **emitter_dicts(cfg, "llvm_ad_rgb"),
            "leafmat": {"type": "twosided", "material": {"type": "diffuse", "reflectance": grid}},
        }
        for s, model in enumerate(inst.species_names):
            low = lib.resolve(model, cfg.base_dir).lods[2]
            d[f"sg_{s}"] = {
                "type": "shapegroup",
                **{
                    f"p{k}": {"type": "ply", "filename": str(p.path), "bsdf": {"type": "ref", "id": "leafmat"}}
                    for k, p in enumerate(low.parts)
                },
            }
        mats = tree_matrices(inst, 1.0 / 24, cfg.wind)
        for i, m in enumerate(mats):
            d[f"tree_{i}"] = {
                "type": "instance",
                "shapegroup": {"type": "ref", "id": f"sg_{int(inst.species[i])}"},
                "to_world": mi.ScalarTransform4f(m),
            }
        t = time.perf_counter()
        sc = mi.load_dict(d)
        load_inst = time.perf_counter() - t
        params = mi.traverse(sc)
        key = [k for k in params.keys() if k.endswith("volume.data")][0]  # noqa: SIM118
        params.keep([key])
        dr.enable_grad(params[key])
        params.update()

        class P:
            pass

        p = P()
        p.scene, p.params = sc, params
        t = time.perf_counter()
        step(p)
        first_inst = time.perf_counter() - t
        t = time.perf_counter()
        step(p)
        inst_s = time.perf_counter() - t
        out[count] = {
            "trees": len(inst),
            "merged_build": build,
            "merged_iter": merged,
            "instanced_load": load_inst,
            "instanced_first": first_inst,
            "instanced_iter": inst_s,
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--skip-proxy", action="store_true")
    ap.add_argument("--only", choices=("round_trip", "unaligned", "proxy"), default=None)
    a = ap.parse_args()
    import warnings

    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory(prefix="forest-bench-lookdev-") as d:
        tmp = Path(d)
        print(f"look-dev benchmark ({os.cpu_count()} CPUs visible)")
        if a.only in (None, "round_trip"):
            rt = round_trip(tmp, a.iterations, a.spp)
            print(
                f"\n1. synthetic round trip (aligned, {a.iterations} iterations x {a.spp} spp, "
                f"{rt['size'][0]}x{rt['size'][1]} px, hidden 8x8 map + sun + sky)"
            )
            print(
                f"   colour map CIEDE2000 over its 64 cells: mean {rt['de_mean']:.2f} (target <= 0.5), "
                f"max {rt['de_max']:.2f} (target <= 2)"
            )
            worst = max(abs(v) for v in rt["lights"].values())
            print(
                "   light values, relative error: "
                + ", ".join(f"{k} {100 * v:+.2f} %" for k, v in rt["lights"].items())
            )
            print(f"   worst light error {100 * worst:.2f} % (target <= 2 %)")
            print(
                f"   image CIEDE2000 to the reference: start {rt['figures']['start_delta_e_mean']:.2f} -> "
                f"result {rt['figures']['result_delta_e_mean']:.2f} (p95 {rt['figures']['result_delta_e_p95']:.2f})"
            )
            print(
                f"   match() wall time {rt['seconds']:.1f} s (target <= 60 s on 2 cores), CPU time "
                f"{rt['cpu_seconds']:.1f} s (all threads); reference render {rt['reference_seconds']:.1f} s"
            )
        if a.only in (None, "unaligned"):
            un = unaligned(tmp, a.iterations, a.spp)
            print("\n2. unaligned photo (statistics mode; another forest of the same density, camera moved 8 m)")
            print(
                f"   global tint CIEDE2000: start {un['start_tint_de']:.2f} -> {un['tint_de']:.2f} (target <= 3); "
                f"fitted tint {np.round(un['tint'], 3).tolist()} vs hidden [0.78, 1.0, 0.62]"
            )
            print(
                f"   sky radiance error: start {100 * un['start_sky']:+.1f} % -> {100 * un['sky']:+.2f} % "
                f"(target within 5 %)"
            )
            print(f"   match() wall time {un['seconds']:.1f} s")
        if a.only in (None, "proxy") and not a.skip_proxy:
            pd = proxy_design(tmp)
            print("\n3. proxy design, llvm_ad_rgb, 64x48 px x 4 spp, forward + backward:")
            for _n, v in pd.items():
                print(
                    f"   {v['trees']} trees: merged proxy {v['merged_iter']:.3f} s/iteration (built in "
                    f"{v['merged_build']:.2f} s); instances {v['instanced_iter']:.3f} s/iteration (first "
                    f"{v['instanced_first']:.1f} s, load {v['instanced_load']:.2f} s); ratio "
                    f"{v['instanced_iter'] / max(v['merged_iter'], 1e-9):.1f}x"
                )
        from forest.runtime import cuda_available

        if not cuda_available():
            print("\nGPU: none on this machine (cuda_ad_rgb timings not measured)")


if __name__ == "__main__":
    main()
