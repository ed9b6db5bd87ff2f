"""Cut cards against quads: the tree library built both ways, and what forest_path and scalar_rgb pay for each.

    .venv/bin/python bench/bench_cards.py                          # every case
    .venv/bin/python bench/bench_cards.py --case render --trees 10000
    .venv/bin/python bench/bench_cards.py --case flythrough --fly-size 960x540 --fly-spp 16

The tree presets are built twice, each into a fresh library of its own: as
shipped (``leaf_cut = "outline"``: leaf, cluster and far cards cut to a convex
outline of their texture's alpha, :mod:`forest.library.outline`) and with
``leaf_cut = "quad"`` (whole quads).  Cases:

* ``build`` — ``Library.build`` of every preset (no previews), both ways: wall
  and CPU seconds and the ratio; the triangles of every level both ways.
* ``outlines`` — per preset and level: the card texture's coverage (mean alpha
  over the quad), the outline's share of the quad, its triangles per card and
  its *fill* (mean alpha over the outline: the share of the rays hitting the
  card that stop on the leaf).
* ``render`` — the scene of ``bench/bench_forest_path.py`` (broadleaf and
  conifer over a procedural terrain, levels of detail by distance) at
  ``--trees``: forest_path in llvm and ``render_image`` in scalar_rgb with each
  library, alternating (each run its own process); time and CPU per frame,
  peak RSS, the llvm/scalar ratio per library and the quad/cut ratio per
  renderer.  Then rays per path in forest_path with each library (counted in
  a separate run, since counting costs time): hits per path on each level's
  leaves and the transparent share.  Looks: cut against quad at the same seed,
  against quad against quad at two seeds (the noise), over 8×8-pixel blocks.
* ``flythrough`` — case study 3 (``configs/flythrough.toml``, 130 000 trees)
  through forest_path (``forest.render.path.from_scene.path_inputs`` +
  ``PathScene``) at ``--fly-size``, ``--fly-spp``, max_depth 3: build and render
  seconds with the cut library (``--fly-quad`` also with quads).

Rays are counted by wrapping ``forest.render.path.integrator.PathKernel._hit``
(every traversal of a path goes through it) with a scatter-add of one per lane
into a counter per (level, part kind).  Figures are printed one per line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_forest_path import cpu_model, cpu_s, load_average, peak_gb, write_scene

TREES = ("broadleaf", "conifer", "palm", "shrub", "fern", "grass")
LEVELS = ("high", "medium", "low", "far")


def quad_library(root: Path) -> Path:
    """A user library whose tree presets shadow the shipped ones with ``leaf_cut = "quad"``."""
    (root / "presets").mkdir(parents=True, exist_ok=True)
    entries = ["version = 1"]
    for name in TREES:
        text = (ROOT / "library/presets" / f"{name}.toml").read_text()
        (root / "presets" / f"{name}.toml").write_text(text.replace("[tree]\n", '[tree]\nleaf_cut = "quad"\n', 1))
        entries.append(f'[species.{name}]\nsource = "generated"\nrecipe = "presets/{name}.toml"\nseed = 1\n')
    (root / "manifest.toml").write_text("\n".join(entries))
    return root


# -- workers (run in a child process, FOREST_LIBRARY naming the library) -------------------------


def worker_build(_args) -> dict:
    from forest.library import open_library
    from forest.runtime import mitsuba

    mitsuba("scalar_rgb")  # import once, outside the timing
    c0, t0 = cpu_s(), time.perf_counter()
    species = open_library().build(previews=False)
    wall, cpu = time.perf_counter() - t0, cpu_s() - c0
    levels = {sp.name: [lod.triangles for lod in sp.lods] for sp in species}
    return {"wall": wall, "cpu": cpu, "levels": levels, "species": len(species)}


def worker_outlines(_args) -> dict:
    """Per tree preset and level: coverage, outline area, triangles per card and fill of the leaf part."""
    from forest.library import open_library
    from forest.library.mesh import components
    from forest.library.textures import read_texture

    lib = open_library()
    out: dict = {}
    for name in TREES:
        sp = lib.get(name)
        rows = []
        for lod in sp.lods:
            leaf = [p for p in lod.parts if p.kind == "leaf"][0]
            m = leaf.load()
            alpha = read_texture(leaf.texture)[..., 3].astype(np.float64)
            n_cards, _ = components(m.faces, len(m.vertices))
            # Outline area: the uv area the cards cover, per card, as a share of the uv rectangle a card spans.
            uv = m.uv.astype(np.float64)[m.faces.astype(np.int64)]
            e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
            a_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
            span = 1.0 if lod.name != "far" else 1.0 / 3.0
            area = float(a_uv.sum()) / (n_cards * span)
            cov = float(alpha.mean())
            rows.append([lod.name, leaf.texture.name, cov, area, m.triangles / n_cards, cov / max(area, 1e-12)])
        out[name] = rows
    return out


def _scene(config: str, overrides: dict):
    from forest.config import load_config
    from forest.library import open_library
    from forest.scatter import scatter
    from forest.scene import load_scene

    cfg = load_config(config, overrides)
    inst, _ = scatter(cfg)
    return cfg, load_scene(cfg, inst, library=open_library())


def worker_path(args) -> dict:
    """forest_path in llvm: build the scene and render the beauty (times, memory, the image saved)."""
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs

    _, scene = _scene(args.config, json.loads(args.overrides))
    c0, t0 = cpu_s(), time.perf_counter()
    ps = PathScene(path_inputs(scene), "llvm_ad_rgb")
    t_build = time.perf_counter() - t0
    t1 = time.perf_counter()
    img = ps.render()
    t_render = time.perf_counter() - t1
    if args.save:
        np.save(args.save, img.rgb)
    st = ps.stats
    return {
        "trees": st.trees,
        "instances": st.instances,
        "flat_triangles": st.flattened_triangles,
        "lod": st.lod_counts,
        "build_s": t_build,
        "render_s": t_render,
        "frame_s": time.perf_counter() - t0,
        "cpu_s": cpu_s() - c0,
        "peak_gb": peak_gb(),
    }


def worker_scalar(args) -> dict:
    """scalar_rgb (``render_image``: scene, beauty, id/depth pass) on the same config."""
    from forest.render.render import render_image

    cfg, scene = _scene(args.config, json.loads(args.overrides))
    rc = cfg.render
    c0, t0 = cpu_s(), time.perf_counter()
    img = render_image(scene, width=rc.width, height=rc.height, spp=rc.spp, variant="scalar_rgb")
    if args.save:
        np.save(args.save, np.asarray(img, np.float32))
    return {"frame_s": time.perf_counter() - t0, "cpu_s": cpu_s() - c0, "peak_gb": peak_gb()}


def worker_rays(args) -> dict:
    """Traversals per path in forest_path, by what they hit: (level, leaf or bark), world parts, misses."""
    import drjit as dr

    from forest.render.path import PathScene
    from forest.render.path import integrator as integ
    from forest.render.path.from_scene import path_inputs

    _, scene = _scene(args.config, json.loads(args.overrides))
    ps = PathScene(path_inputs(scene), "llvm_ad_rgb")
    mi = ps.mi
    kinds = ps.materials.table().kind
    code = np.full(len(ps.geometry.parts.triangles), 8, np.uint32)  # 8: terrain and other world parts
    for (_, _, level), proto in ps.geometry.prototypes.items():
        for p in proto.parts:
            code[p] = 2 * level + int(kinds[ps.geometry.parts.material[p]] == 1)
    codes, count, opaque = mi.UInt32(code), dr.zeros(mi.Float, 10), dr.zeros(mi.Float, 10)
    traced = integ.PathKernel._hit

    def counted(self, o, d, maxt, active, coherent=False):
        hit = traced(self, o, d, maxt, active, coherent)
        c = dr.select(hit.valid, dr.gather(mi.UInt32, codes, hit.part, hit.valid), 9)  # 9: a miss
        dr.scatter_reduce(dr.ReduceOp.Add, count, mi.Float(1.0), c, active)
        dr.scatter_reduce(dr.ReduceOp.Add, opaque, self._alpha(hit, hit.valid), c, active & hit.valid)
        return hit

    integ.PathKernel._hit = counted
    img = ps.render()
    paths = float(img.rgb.shape[0] * img.rgb.shape[1] * img.spp)
    return {"count": (np.asarray(count) / paths).tolist(), "opaque": (np.asarray(opaque) / paths).tolist()}


WORKERS = {
    "build": worker_build,
    "outlines": worker_outlines,
    "path": worker_path,
    "scalar": worker_scalar,
    "rays": worker_rays,
}


def run(kind: str, library: Path, **kw) -> dict:
    cmd = [sys.executable, __file__, "--worker", kind] + [f"--{k.replace('_', '-')}={v}" for k, v in kw.items()]
    env = dict(os.environ, FOREST_LIBRARY=str(library))
    r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = [line[line.index('{"') :] for line in r.stdout.strip().splitlines() if '{"' in line]
    if r.returncode != 0 or not lines:
        raise SystemExit(f"bench worker {kind} failed:\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    return json.loads(lines[-1])


# -- cases ---------------------------------------------------------------------------------------


def case_build(libs: dict[str, Path]) -> None:
    res = {tag: run("build", lib) for tag, lib in libs.items()}
    c, q = res["cut"], res["quad"]
    print(
        f"cards build: {c['species']} presets, no previews: cut {c['wall']:.1f} s wall / {c['cpu']:.1f} CPU-s, "
        f"quad {q['wall']:.1f} s wall / {q['cpu']:.1f} CPU-s: cut/quad {c['wall'] / q['wall']:.2f} wall"
    )
    for name in TREES:
        tc, tq = c["levels"][name], q["levels"][name]
        print(
            f"cards triangles {name:9s} "
            + "  ".join(f"{lv} {a:,}/{b:,}" for lv, a, b in zip(LEVELS, tc, tq))
            + "  (cut/quad)"
        )


def case_outlines(libs: dict[str, Path]) -> None:
    res = {tag: run("outlines", lib) for tag, lib in libs.items()}
    for name in TREES:
        for c, q in zip(res["cut"][name], res["quad"][name]):
            print(
                f"cards outline {name:9s} {c[0]:6s} {c[1]:11s} coverage {c[2]:.3f}: cut card {c[3]:.3f} of the quad, "
                f"{c[4]:.1f} triangles a card, fill {c[5]:.2f} (quad: {q[4]:.1f} triangles, fill {q[5]:.2f})"
            )


def _blocks(img: np.ndarray, k: int = 8) -> np.ndarray:
    h, w = (img.shape[0] // k) * k, (img.shape[1] // k) * k
    return img[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


def case_render(tmp: Path, libs: dict[str, Path], trees: int, width: int, height: int, spp: int, depth: int) -> None:
    print(f"cards render: {cpu_model()}, {os.cpu_count()} cores; load average {load_average()} at start")
    cfg = write_scene(tmp, count=trees, width=width, height=height, spp=spp, depth=depth)
    noop = json.dumps({})
    res: dict[str, dict] = {}
    for tag in ("quad", "cut"):  # alternate the renderers so a busy machine slows both alike
        res[tag] = {
            "path": run("path", libs[tag], config=cfg, overrides=noop, save=tmp / f"{tag}.npy"),
            "scalar": run("scalar", libs[tag], config=cfg, overrides=noop, save=""),
        }
    seed1 = tmp / "bench_seed1"
    cfg1 = write_scene(seed1, count=trees, width=width, height=height, spp=spp, depth=depth, seed=1)
    run("path", libs["quad"], config=cfg1, overrides=noop, save=tmp / "quad_seed1.npy")
    for tag in ("quad", "cut"):
        p, s = res[tag]["path"], res[tag]["scalar"]
        print(
            f"cards render {tag:4s} {p['trees']:,} trees {width}x{height} {spp} spp max_depth {depth}: forest_path llvm "
            f"{p['frame_s']:.1f} s wall / {p['cpu_s']:.1f} CPU-s (build {p['build_s']:.1f} s, render "
            f"{p['render_s']:.1f} s), peak {p['peak_gb']:.2f} GiB | scalar_rgb {s['frame_s']:.1f} s wall / "
            f"{s['cpu_s']:.1f} CPU-s, peak {s['peak_gb']:.2f} GiB | scalar/llvm {s['frame_s'] / p['frame_s']:.2f} wall, "
            f"{s['cpu_s'] / p['cpu_s']:.2f} CPU"
        )
    for r in ("path", "scalar"):
        q, c = res["quad"][r], res["cut"][r]
        print(
            f"cards render {'forest_path' if r == 'path' else 'scalar_rgb'}: quad/cut time "
            f"{q['frame_s'] / c['frame_s']:.2f} wall, {q['cpu_s'] / c['cpu_s']:.2f} CPU"
        )
    quad, cut, quad1 = (np.load(tmp / f"{n}.npy").astype(np.float64) for n in ("quad", "cut", "quad_seed1"))
    bq, bc, b1 = _blocks(quad), _blocks(cut), _blocks(quad1)
    print(
        f"cards render look: mean cut/quad {cut.mean() / quad.mean():.4f}; 8x8-block RMS difference cut vs quad "
        f"{np.sqrt(np.mean((bc - bq) ** 2)):.5f}, quad vs quad at another seed {np.sqrt(np.mean((b1 - bq) ** 2)):.5f} "
        f"(noise), image mean {quad.mean():.4f}"
    )
    names = [f"{lv} {k}" for lv in LEVELS for k in ("bark", "leaf")] + ["world", "miss"]
    small = json.dumps({"render.width": max(width // 2, 16), "render.height": max(height // 2, 9)})
    counts = {tag: run("rays", libs[tag], config=cfg, overrides=small) for tag in ("quad", "cut")}
    for tag, r in counts.items():
        n, a = np.array(r["count"]), np.array(r["opaque"])
        parts = [
            f"{names[i]} {n[i]:.2f} (transparent {n[i] - a[i]:.2f})" for i in range(len(n)) if n[i] > 0.005 and i < 9
        ]
        print(f"cards rays {tag:4s}: {n.sum():.2f} traversals per path: " + ", ".join(parts) + f", miss {n[9]:.2f}")
    nq, nc = sum(counts["quad"]["count"]), sum(counts["cut"]["count"])
    print(f"cards rays: traversals per path quad/cut {nq / nc:.2f}")
    print(f"cards render: load average {load_average()} at end")


def case_flythrough(libs: dict[str, Path], size: str, spp: int, quads: bool) -> None:
    w, h = (int(v) for v in size.lower().split("x"))
    over = json.dumps({"render.width": w, "render.height": h, "render.spp": spp, "render.max_depth": 3})
    cfg = ROOT / "configs/flythrough.toml"
    print(f"cards flythrough: load average {load_average()} at start")
    for tag in ("cut", "quad") if quads else ("cut",):
        r = run("path", libs[tag], config=cfg, overrides=over, save="")
        print(
            f"cards flythrough {tag:4s} (case study 3) {r['trees']:,} trees ({r['instances']:,} instances, "
            f"{r['flat_triangles']:,} merged far triangles; levels {r['lod']}), {w}x{h} {spp} spp max_depth 3: "
            f"forest_path llvm {r['frame_s']:.1f} s end to end (build {r['build_s']:.1f} s, render "
            f"{r['render_s']:.1f} s), {r['cpu_s']:.1f} CPU-s, peak {r['peak_gb']:.2f} GiB (goal ≤ 180 s at 1920x1080x64)"
        )
    print(f"cards flythrough: load average {load_average()} at end")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="all", help="build, outlines, render, flythrough or all")
    ap.add_argument("--trees", type=int, default=10_000)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=270)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=3)
    ap.add_argument("--fly-size", default="1920x1080")
    ap.add_argument("--fly-spp", type=int, default=64)
    ap.add_argument("--fly-quad", action="store_true", help="also render the flythrough with quads")
    ap.add_argument("--keep", default="", help="build the libraries into this folder and keep them")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--config", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--overrides", default="{}", help=argparse.SUPPRESS)
    ap.add_argument("--save", default="", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(WORKERS[args.worker](args)))
        return
    cases = ["build", "outlines", "render", "flythrough"] if args.case == "all" else args.case.split(",")
    with tempfile.TemporaryDirectory(prefix="forest-bench-cards-") as d:
        base = Path(args.keep) if args.keep else Path(d)
        libs = {"cut": base / "cut", "quad": quad_library(base / "quad")}
        libs["cut"].mkdir(parents=True, exist_ok=True)
        if "build" not in cases:  # the others need the libraries built
            for lib in libs.values():
                run("build", lib)
        tmp = Path(d) / "scenes"
        for c in cases:
            if c == "build":
                case_build(libs)
            elif c == "outlines":
                case_outlines(libs)
            elif c == "render":
                case_render(tmp, libs, args.trees, args.width, args.height, args.spp, args.max_depth)
            elif c == "flythrough":
                case_flythrough(libs, args.fly_size, args.fly_spp, args.fly_quad)
            else:
                raise SystemExit(f"unknown case {c!r}")


if __name__ == "__main__":
    main()
