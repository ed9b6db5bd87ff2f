"""forest_path on the GPU (``cuda_ad_rgb``) beside the CPU (``llvm_ad_rgb``) on the same machine.

    python bench/bench_gpu.py [--cases probe demo original million lookdev] [--variants cuda_ad_rgb llvm_ad_rgb]
                              [--timeout 120] [--out DIR]

Every case runs in a child process under its own time limit (a case that runs past it prints
``TIMEOUT`` and the next one starts), so one device run measures them all:

* ``probe`` — the demo at 320×180, 4 spp through :class:`forest.render.path.PathScene`: load and
  per-pass seconds, the per-lane segment counters against their bound
  (:func:`forest.render.path.integrator.segment_cap`), where the time goes (drjit's kernel
  history: each launch's size, op count, compile and execution time), and the image, compared
  across variants (relative mean difference of the two renders: same seeds, so only the
  floating-point differences of the two back-ends remain);
* ``demo`` — ``forest render configs/demo.toml`` at its own 800×450, 12 spp (target on an H100/H200:
  ≤ 2 s of render), twice: with its kernels compiled in the run, then with drjit's kernel cache warm;
* ``original`` — the 2005 case study 3: 130 000 trees, 1920×1080, 64 spp, max_depth 3
  (target ≤ 10 s of render);
* ``default`` — the case study with default settings (no ``[lod]``: automatic levels of detail and solid
  cards; the default ``max_depth``), as ``bench/bench_render.py --case default`` renders it on the CPU;
* ``million`` — 1 000 000 trees at 1280×720, 16 spp: time and peak memory (GPU memory from
  drjit's allocator where the variant is cuda);
* ``repose`` — what a motion-blurred sub-frame with wind costs: the fly-through's 130 000 trees through
  :class:`forest.render.path.PathScene`, built once, then moved to the wind of a later instant by rebuilding
  the Mitsuba scene (:meth:`PathScene.pose`, what forest does) and by updating the instances' ``to_world``
  and the merged meshes' vertices in place (``mi.traverse`` + ``SceneParameters.update``, an experiment kept
  here); seconds of each and the two images' relative mean difference (the same geometry: 0 up to
  floating point);
* ``flatten`` — instancing against merging: a 20 000-tree case-study scene built with trees of at most 64
  (forest's default), 1 500 (the low level) and 12 000 (the medium level) triangles merged into
  world-space meshes: build and one-pass render seconds, instances left, GPU memory (cuda), and the
  images against the default's;
* ``flatten_default`` — the same three limits for the case study with default settings (130 000 trees,
  1920×1080, automatic levels, default ``max_depth``): what merging the low and medium levels would save of a
  GPU's scene build (about 400 µs an instance on an H200);
* ``instances`` — what one Mitsuba instance costs to build, four ways, on 20 000 instances of a cube:
  ``load_dict`` of the scene's dict with ``parallel=True`` (what forest does) and ``parallel=False``, and
  each instance made alone (``load_dict`` of its own dict) before the scene is made of the objects
  (µs per instance; on 2 CPU cores, past a process's first build, about 37–40 parallel, 32–33 serial and
  29 + 3.4 made alone: Mitsuba's parallel loading gains nothing there);
* ``lookdev`` — an aligned look-dev round trip: the demo rendered as a reference at 192×108, then
  ``forest match`` fitting it from the demo's config (target ≤ 10 s).

``--profile DIR`` runs each ``forest render`` under :mod:`cProfile` and keeps ``DIR/<case>_<variant>.prof``
(host time by function; a kernel's execution shows where the host waits for it).

Render seconds come from ``forest render``'s summary line (scene load and render apart; the first
run of a kernel includes its compilation, which drjit caches on disk for the runs after).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CASES = (
    "probe",
    "demo",
    "original",
    "default",
    "million",
    "repose",
    "flatten",
    "flatten_default",
    "instances",
    "lookdev",
)
#: Where ``render_case`` keeps a cProfile of each render (``--profile``); None: no profiling.
PROFILE: Path | None = None
VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb")
SUMMARY = re.compile(r"load ([\d.]+) s, render ([\d.]+) s, peak ([\d.]+) GiB(?: \(GPU ([\d.]+) GiB\))?")


def forest_cmd() -> list[str]:
    """The ``forest`` command beside this interpreter (an installed forest), else forest's CLI through it."""
    exe = Path(sys.executable).parent / "forest"
    return [str(exe)] if exe.exists() else [sys.executable, "-c", "from forest.cli import main; main()"]


def run(cmd: list[str], timeout: float, env: dict[str, str] | None = None) -> tuple[str, float, str]:
    """(status, wall seconds, output) of a child process: status is ``ok``, ``failed (rc)`` or ``TIMEOUT``."""
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as e:
        out = "".join(x.decode() if isinstance(x, bytes) else x for x in (e.stdout or "", e.stderr or ""))
        return "TIMEOUT", time.perf_counter() - t0, out
    status = "ok" if r.returncode == 0 else f"failed ({r.returncode})"
    return status, time.perf_counter() - t0, r.stdout + r.stderr


def render_line(out: str) -> str:
    return next((line for line in out.splitlines() if line.startswith("rendered")), "")


def render_case(name: str, config: Path, variant: str, out: Path, timeout: float, extra: list[str] = ()) -> dict:
    """``forest render CONFIG --variant V`` end to end; load and render seconds from its summary."""
    stem = f"{name.replace(', ', '_')}_{variant}"
    exr = out / f"{stem}.exr"
    cmd = forest_cmd()
    if PROFILE is not None and len(cmd) == 1:
        cmd = [sys.executable, "-m", "cProfile", "-o", str(PROFILE / f"{stem}.prof"), *cmd]
    status, wall, text = run([*cmd, "render", str(config), "-o", str(exr), "--variant", variant, *extra], timeout)
    if status == "ok" and not render_line(text):  # cProfile swallows the command's exit status
        status = "failed (no summary line)"
    m = SUMMARY.search(render_line(text))
    r = {"case": name, "variant": variant, "status": status, "wall_s": wall, "summary": render_line(text)}
    if m:
        r.update(load_s=float(m.group(1)), render_s=float(m.group(2)), peak_gb=float(m.group(3)))
        if m.group(4):
            r["gpu_peak_gb"] = float(m.group(4))
    if status != "ok":
        r["tail"] = text[-1500:]
    return r


def scene_file(folder: Path, **kw) -> Path:
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_render import write_scene

    folder.mkdir(parents=True, exist_ok=True)
    return write_scene(folder, **kw)


# -- the probe (child process) ------------------------------------------------------------------------------------


def worker_probe(variant: str, out: Path, width: int, height: int, spp: int, max_depth: int | None = None) -> dict:
    import drjit as dr

    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.render.path.integrator import segment_cap
    from forest.scene import load_scene

    t0 = time.perf_counter()
    scene = load_scene(load_config(ROOT / "configs" / "demo.toml"))
    inputs = path_inputs(scene, width=width, height=height, spp=spp)
    path = PathScene(inputs, variant)
    t_load = time.perf_counter() - t0
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    if os.environ.get("FOREST_JIT_LOG"):  # every launch, its size, ops and compile/cache status, on stderr
        dr.set_log_level(dr.LogLevel.Info)
    passes, segs, rgb = [], [], []
    t1 = time.perf_counter()
    for p in path.passes(spp=spp, aux=True, max_depth=max_depth):
        passes.append(round(time.perf_counter() - t1, 3))
        segs.append(p.segments.ravel())
        rgb.append(p.rgb / p.spp)
    history = dr.kernel_history()
    s = np.concatenate(segs)
    cap = segment_cap(max_depth or inputs.max_depth)
    image = np.mean(rgb, axis=0).reshape(height, width, 3).astype(np.float32)
    np.save(out / f"probe_{variant}.npy", image)
    kernels = sorted(
        (
            {
                "size": int(k.get("size", 0)),
                "ops": int(k.get("operation_count", 0)),
                "exec_ms": float(k.get("execution_time", 0.0)),
                "compile_ms": float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0)),
                "cache_hit": bool(k.get("cache_hit", False)),
            }
            for k in history
            if k.get("type") == dr.KernelType.JIT
        ),
        key=lambda k: -k["exec_ms"],
    )
    return {
        "case": "probe",
        "variant": variant,
        "status": "ok",
        "max_depth": max_depth or inputs.max_depth,
        "load_s": t_load,
        "pass_s": passes,
        "segments": {
            "cap": cap,
            "max": int(s.max()),
            "mean": float(s.mean()),
            "p999": float(np.quantile(s, 0.999)),
            "at_guard": int((s > cap).sum()),
        },
        "kernels": kernels[:6],
        "kernel_exec_s": sum(k["exec_ms"] for k in kernels) / 1000.0,
        "kernel_compile_s": sum(k["compile_ms"] for k in kernels) / 1000.0,
        "image_mean": image.reshape(-1, 3).mean(axis=0).round(5).tolist(),
    }


def update_in_place(mi, traversal, geometry, matrices: np.ndarray) -> dict:
    """Move a built traversal scene's trees to ``matrices`` without rebuilding it (the ``repose`` experiment):
    each instance's ``to_world``, each merged mesh's world vertices, and the hit tables' row matrices."""
    import drjit as dr

    from forest.render.path.arrays import owned
    from forest.render.path.geometry import normal_matrices

    t0 = time.perf_counter()
    params = mi.traverse(traversal.scene)
    t1 = time.perf_counter()
    mats = np.ascontiguousarray(matrices, np.float64)
    T, M4 = mi.ScalarTransform4f, mi.ScalarMatrix4f
    flat_rows = np.asarray(traversal.flat_rows, np.int64)
    parts = geometry.parts
    moved = 0
    keys = list(params.keys())
    for key in keys:
        if key.startswith("tree_") and key.endswith(".to_world"):
            params[key] = T(M4(mats[int(key[5:-9])]))
            moved += 1
        elif key.startswith("flat_") and key.endswith(".vertex_positions"):
            part = key[: -len(".vertex_positions")].split("_")[2]
            v = parts.vertices[int(part)].astype(np.float64)
            count = dr.width(params[key]) // (3 * len(v))
            off = traversal.flat_offsets[key[: -len(".vertex_positions")]]
            m = mats[flat_rows[off : off + count]]
            world = np.einsum("nij,vj->nvi", m[:, :3, :3], v) + m[:, None, :3, 3]
            params[key] = mi.Float(world.astype(np.float32).ravel())
    t2 = time.perf_counter()
    params.update()
    n = len(mats)
    mat3 = np.zeros((n + 1, 3, 4), np.float32)
    mat3[:n] = mats[:, :3, :]
    mat3[n, :, :3] = np.eye(3)
    nrm = np.zeros((n + 1, 3, 3), np.float32)
    nrm[:n] = normal_matrices(mats)
    nrm[n] = np.eye(3)
    traversal.row_matrix = owned(mi.Float, mat3.ravel())
    traversal.row_normal = owned(mi.Float, nrm.ravel())
    dr.eval()
    t3 = time.perf_counter()
    return {"traverse_s": t1 - t0, "set_s": t2 - t1, "update_s": t3 - t2, "moved": moved}


def _pass_image(path, spp: int = 2) -> np.ndarray:
    return np.sum([p.rgb / p.spp for p in path.passes(spp=spp, seed=3)], axis=0)


def _rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).mean() / max(float(np.abs(b).mean()), 1e-12))


def worker_repose(variant: str) -> dict:
    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene
    from forest.wind import tree_matrices

    config = load_config(ROOT / "configs" / "flythrough.toml")
    scene = load_scene(config)
    inputs = path_inputs(scene, width=480, height=270, spp=2)
    t0 = time.perf_counter()
    path = PathScene(inputs, variant)
    build = time.perf_counter() - t0
    st = path.traversal.stats
    later = tree_matrices(scene.instances, 1.0 / config.camera.fps, config.wind)
    t0 = time.perf_counter()
    path.pose(inputs.levels, later, solid=inputs.solid)
    rebuild = time.perf_counter() - t0
    rebuilt = _pass_image(path)
    path.pose(inputs.levels, inputs.matrices, solid=inputs.solid)  # back to the first instant, rebuilt
    t0 = time.perf_counter()
    timing = update_in_place(path.mi, path.traversal, path.geometry, later)
    update = time.perf_counter() - t0
    updated = _pass_image(path)
    return {
        "case": "repose",
        "variant": variant,
        "status": "ok",
        "instances": st.instances,
        "merged_trees": st.flattened_trees,
        "build_s": build,
        "rebuild_s": rebuild,
        "in_place_s": update,
        **timing,
        "relative_mean_difference": _rel_diff(updated, rebuilt),
    }


#: The ``flatten`` cases: (trees requested, width, height, ``[lod]`` line or None for the automatic levels).
FLATTEN_CASES = {
    "flatten": (20_000, 480, 270, "distances = [150.0, 600.0, 1800.0]"),
    "flatten_default": (130_000, 1920, 1080, None),
}


def worker_flatten(variant: str, out: Path, name: str = "flatten") -> dict:
    import dataclasses

    import drjit as dr

    from forest.config import load_config
    from forest.render.path import PathScene
    from forest.render.path.from_scene import path_inputs
    from forest.scene import load_scene

    count, width, height, lod = FLATTEN_CASES[name]
    cfg = scene_file(out / name, count=count, width=width, height=height, spp=4, lod=lod, depth=3 if lod else None)
    scene = load_scene(load_config(cfg))
    base = path_inputs(scene, width=width, height=height, spp=4)
    rows, ref = [], None
    for limit in (64, 1_500, 12_000):
        t0 = time.perf_counter()
        path = PathScene(dataclasses.replace(base, flatten_triangles=limit), variant)
        build = time.perf_counter() - t0
        st = path.traversal.stats
        _pass_image(path, 1)  # compiles the kernel
        t0 = time.perf_counter()
        image = _pass_image(path, 4)
        render = time.perf_counter() - t0
        ref = image if ref is None else ref
        gpu = float(dr.detail.malloc_watermark(dr.JitBackend.CUDA)) / 2**30 if variant.startswith("cuda") else None
        rows.append({"merge_up_to": limit, "instances": st.instances, "merged_trees": st.flattened_trees,
                     "merged_triangles": st.flattened_triangles, "build_s": round(build, 2),
                     "render_s": round(render, 2), "gpu_watermark_gb": gpu,
                     "relative_mean_difference": _rel_diff(image, ref)})  # fmt: skip
        del path
    return {"case": name, "variant": variant, "status": "ok", "rows": rows}


def worker_instances(variant: str, count: int = 20_000) -> dict:
    import mitsuba as mi

    from forest.runtime import mitsuba

    mitsuba(variant)
    T = mi.ScalarTransform4f
    pos = np.random.default_rng(0).uniform(-500.0, 500.0, (count, 3)).tolist()
    us: dict[str, float] = {}
    for parallel in (True, False):
        # A shapegroup of its own for each scene: with one shared by all three the case died in cuda_ad_rgb
        # (SIGSEGV, H200, Nov 28); whether the sharing was the cause is untested.
        group = mi.load_dict({"type": "shapegroup", "c": {"type": "cube"}})
        entries = {"type": "scene", "g": group}
        entries.update({f"tree_{i}": {"type": "instance", "shapegroup": group, "to_world": T().translate(pos[i])}
                        for i in range(count)})  # fmt: skip
        t0 = time.perf_counter()
        scene = mi.load_dict(entries, parallel=parallel)
        us[f"scene_dict_parallel_{parallel}"] = (time.perf_counter() - t0) / count * 1e6
        del scene, entries
    group = mi.load_dict({"type": "shapegroup", "c": {"type": "cube"}})
    t0 = time.perf_counter()
    objects = [mi.load_dict({"type": "instance", "shapegroup": group, "to_world": T().translate(pos[i])})
               for i in range(count)]  # fmt: skip
    us["objects_one_by_one"] = (time.perf_counter() - t0) / count * 1e6
    entries = {"type": "scene", "g": group, **{f"tree_{i}": o for i, o in enumerate(objects)}}
    t0 = time.perf_counter()
    mi.load_dict(entries)
    us["scene_of_objects"] = (time.perf_counter() - t0) / count * 1e6
    return {"case": "instances", "variant": variant, "status": "ok", "instances": count,
            "us_per_instance": {k: round(v, 1) for k, v in us.items()}}  # fmt: skip


def case_instances(variants: list[str], out: Path, timeout: float) -> list[dict]:
    return case_worker("instances", variants, out, timeout)


def case_worker(name: str, variants: list[str], out: Path, timeout: float, extra: list[str] = ()) -> list[dict]:
    """A worker case in a child process per variant (its JSON line, or the status and the output's tail)."""
    rows = []
    for v in variants:
        cmd = [sys.executable, __file__, "--worker", name, "--variant", v, "--out", str(out), *extra]
        status, wall, text = run(cmd, timeout)
        lines = [line for line in text.splitlines() if line.startswith('{"case"')]
        r = json.loads(lines[-1]) if lines else {"case": name, "variant": v, "status": status, "tail": text[-2500:]}
        r["wall_s"] = wall
        rows.append(r)
    return rows


def case_repose(variants: list[str], out: Path, timeout: float) -> list[dict]:
    return case_worker("repose", variants, out, timeout)


def case_flatten(variants: list[str], out: Path, timeout: float) -> list[dict]:
    return case_worker("flatten", variants, out, timeout)


def case_flatten_default(variants: list[str], out: Path, timeout: float) -> list[dict]:
    return case_worker("flatten_default", variants, out, timeout)


# -- cases ----------------------------------------------------------------------------------------------------------


def case_probe(
    variants: list[str], out: Path, timeout: float, size: str = "320x180", spp: int = 4, max_depth: int | None = None
) -> list[dict]:
    extra = ["--size", size, "--spp", str(spp)] + ([] if max_depth is None else ["--max-depth", str(max_depth)])
    rows = case_worker("probe", variants, out, timeout, extra)
    images = {v: out / f"probe_{v}.npy" for v in variants if (out / f"probe_{v}.npy").exists()}
    if len(images) == 2:
        a, b = (np.load(p) for p in images.values())
        rows.append(
            {
                "case": "probe",
                "variant": "compare",
                "status": "ok",
                "relative_mean_difference": float(np.abs(a - b).mean() / max(np.abs(b).mean(), 1e-12)),
                "means": [a.reshape(-1, 3).mean(0).round(5).tolist(), b.reshape(-1, 3).mean(0).round(5).tolist()],
            }
        )
    return rows


def case_demo(variants: list[str], out: Path, timeout: float) -> list[dict]:
    """The demo twice per variant: first with its kernels compiled in the run (``demo``), then again with drjit's
    kernel cache warm (``demo, cached``), which lists the compilation apart."""
    rows = []
    for v in variants:
        rows.append(render_case("demo", ROOT / "configs" / "demo.toml", v, out, timeout))
        rows.append(render_case("demo, cached", ROOT / "configs" / "demo.toml", v, out, timeout))
    return rows


def case_original(variants: list[str], out: Path, timeout: float) -> list[dict]:
    cfg = scene_file(out / "original", count=130_000, width=1920, height=1080, spp=64, depth=3,
                     lod="distances = [150.0, 600.0, 1800.0]")  # fmt: skip
    return [render_case("original", cfg, v, out, timeout) for v in variants]


def case_default(variants: list[str], out: Path, timeout: float) -> list[dict]:
    cfg = scene_file(out / "default", count=130_000, width=1920, height=1080, spp=64, depth=None, lod=None)
    return [render_case("default", cfg, v, out, timeout) for v in variants]


def case_million(variants: list[str], out: Path, timeout: float) -> list[dict]:
    cfg = scene_file(out / "million", count=1_000_000, width=1280, height=720, spp=16,
                     lod="distances = [150.0, 600.0, 1800.0]")  # fmt: skip
    return [render_case("million", cfg, v, out, timeout) for v in variants]


def case_lookdev(variants: list[str], out: Path, timeout: float) -> list[dict]:
    demo = ROOT / "configs" / "demo.toml"
    rows = []
    for v in variants:
        ref = out / f"lookdev_ref_{v}.exr"
        status, _, text = run([*forest_cmd(), "render", str(demo), "-o", str(ref), "--width", "192", "--height", "108",
                               "--spp", "16", "--variant", v, "-q"], timeout)  # fmt: skip
        if status != "ok":
            rows.append({"case": "lookdev", "variant": v, "status": f"reference {status}", "tail": text[-1500:]})
            continue
        cmd = [*forest_cmd(), "match", str(demo), "-r", str(ref.with_suffix(".png")), "-o", str(out / f"match_{v}"),
               "--mode", "aligned", "--variant", v]  # fmt: skip
        status, wall, text = run(cmd, timeout)
        fitted = next((line for line in text.splitlines() if line.startswith("fitted")), "")
        r = {"case": "lookdev", "variant": v, "status": status, "wall_s": wall, "summary": fitted}
        m = re.search(r"in ([\d.]+) s", fitted)
        if m:
            r["fit_s"] = float(m.group(1))
        if status != "ok":
            r["tail"] = text[-1500:]
        rows.append(r)
    return rows


def report(rows: list[dict]) -> None:
    by_case: dict[str, dict[str, dict]] = {}
    for r in rows:
        by_case.setdefault(r["case"], {})[r["variant"]] = r
    print("\n| case | variant | status | load s | render s | wall s | peak GB | GPU peak GB |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if r["variant"] == "compare":
            continue
        render = r.get("render_s", r.get("fit_s", sum(r.get("pass_s", [])) if "pass_s" in r else None))
        cells = [r["case"], r["variant"], r["status"], r.get("load_s"), render, r.get("wall_s"), r.get("peak_gb"),
                 r.get("gpu_peak_gb")]  # fmt: skip
        print("| " + " | ".join(f"{c:.2f}" if isinstance(c, float) else str(c) for c in cells) + " |")
    for case, rs in by_case.items():
        g, c = rs.get("cuda_ad_rgb", {}), rs.get("llvm_ad_rgb", {})
        key = "render_s" if "render_s" in g else "fit_s"
        if key in g and key in c:
            print(f"{case}: llvm_ad_rgb / cuda_ad_rgb render time = {c[key] / max(g[key], 1e-9):.1f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=list(CASES), choices=CASES)
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=VARIANTS)
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds each child process may run")
    ap.add_argument("--out", default=None)
    ap.add_argument("--profile", default=None, metavar="DIR", help="keep a cProfile of each forest render in DIR")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--variant", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--size", default="320x180", help="probe image size")
    ap.add_argument("--spp", type=int, default=4, help="probe samples per pixel")
    ap.add_argument("--max-depth", type=int, default=None, help="probe max_depth (default: the demo's)")
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="bench_gpu_"))
    out.mkdir(parents=True, exist_ok=True)
    if a.worker == "probe":
        w, h = (int(x) for x in a.size.split("x"))
        print(json.dumps(worker_probe(a.variant, out, w, h, a.spp, a.max_depth)))
        return
    if a.worker == "instances":
        print(json.dumps(worker_instances(a.variant)))
        return
    if a.worker == "repose":
        print(json.dumps(worker_repose(a.variant)))
        return
    if a.worker in FLATTEN_CASES:
        print(json.dumps(worker_flatten(a.variant, out, a.worker)))
        return
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    if a.profile:
        global PROFILE
        PROFILE = Path(a.profile)
        PROFILE.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    for case in a.cases:
        kw = {"size": a.size, "spp": a.spp, "max_depth": a.max_depth} if case == "probe" else {}
        got = globals()[f"case_{case}"](a.variants, out, a.timeout, **kw)
        for r in got:
            print(json.dumps(r), flush=True)
        rows += got
    report(rows)


if __name__ == "__main__":
    main()
