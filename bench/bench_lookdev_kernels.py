"""Look-dev's kernel compilations on a cold kernel cache: scene parameters as kernel parameters against literals.

    .venv/bin/python bench/bench_lookdev_kernels.py [--runs 1] [--variant llvm_ad_rgb]

Look-dev sets the scene's lights, tints and haze to new values at every step.  A drjit value made from Python
numbers (``mi.Color3f(r, g, b)``) is a literal, written into the code of the kernels that read it, so each new
value compiled a new path kernel (1.0-1.6 s each on 2 CPU cores, about 1 s on a GPU);
:func:`forest.render.path.arrays.opaque` holds it in memory instead.

Each run is a child process with an empty drjit kernel cache of its own (``HOME`` pointed at a temporary folder,
forest's data, cache and state folders kept; on a GPU OptiX's disk cache is off), so every distinct kernel
compiles, as on a fresh machine or a fresh GPU: ``forest match configs/demo.toml --mode aligned`` against the demo's own 192x108, 16 spp render.
The baseline is the same command with ``opaque`` replaced by the literal it was before.  Printed per run:
distinct path kernels (over 3 000 operations), kernels compiled and their compilation seconds, launches, the
fit's seconds and the whole command's wall seconds; then the ratios.  Alternating runs, best of ``--runs``.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from timing import load_line


def forest_cmd() -> list[str]:
    """The ``forest`` command beside this interpreter (a virtual environment's, or an installed forest's on a GPU
    machine), else forest's CLI through this interpreter."""
    exe = Path(sys.executable).parent / "forest"
    return [str(exe)] if exe.exists() else [sys.executable, "-c", "from forest.cli import main; main()"]


CHILD = r"""
import atexit, json, sys
import drjit as dr
if sys.argv[1] == "literal":
    import forest.lookdev.renders as R
    import forest.render.path.arrays as A
    import forest.render.path.emitters as E
    import forest.render.path.frame as F
    import forest.render.path.haze as H

    def literal(cls, *values):
        return cls(*(float(v) for v in values))

    for module in (A, E, F, H, R):
        module.opaque = literal
dr.set_flag(dr.JitFlag.KernelHistory, True)


def report():
    jit = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
    big = [k for k in jit if k.get("operation_count", 0) > 3000]
    compiled = [k for k in jit if not k.get("cache_hit")]
    print(json.dumps({"distinct_path_kernels": len({k["hash"] for k in big}), "compiled": len(compiled),
                      "compile_s": sum(k.get("backend_time", 0.0) + k.get("codegen_time", 0.0) for k in compiled) / 1e3,
                      "launches": len(jit)}))


atexit.register(report)
from forest.cli import main

sys.argv = ["forest", *sys.argv[2:]]
main()
"""


def match(kind: str, demo: Path, ref: Path, out: Path, variant: str) -> dict:
    """One ``forest match`` in a child process with an empty drjit kernel cache; its figures."""
    with tempfile.TemporaryDirectory() as home:
        real = Path.home()
        env = dict(os.environ, HOME=home, PYTHONUNBUFFERED="1", OPTIX_CACHE_MAXSIZE="0")  # no OptiX disk cache
        for key, default in (("XDG_DATA_HOME", ".local/share"), ("XDG_CACHE_HOME", ".cache"),
                             ("XDG_STATE_HOME", ".local/state")):  # fmt: skip
            env.setdefault(key, str(real / default))
        cmd = [sys.executable, "-c", CHILD, kind, "match", str(demo), "-r", str(ref), "-o", str(out),
               "--mode", "aligned", "--variant", variant]  # fmt: skip
        t0 = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"bench_lookdev_kernels: forest match failed:\n{run.stderr[-2000:]}")
    figures = json.loads([line for line in run.stdout.splitlines() if line.startswith("{")][-1])
    fitted = next((line for line in run.stdout.splitlines() if line.startswith("fitted")), "")
    m = re.search(r"in ([\d.]+) s", fitted)
    objective = next((line for line in run.stdout.splitlines() if line.startswith("objective")), "")
    return {**figures, "fit_s": float(m.group(1)) if m else float("nan"), "wall_s": wall, "objective": objective}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()
    print(f"lookdev kernels: {load_line()} at start; {args.variant}, every run with an empty kernel cache")
    demo = ROOT / "configs" / "demo.toml"
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        ref = tmp / "ref.exr"
        subprocess.run([*forest_cmd(), "render", str(demo), "-o", str(ref), "--width", "192", "--height", "108",
                        "--spp", "16", "--variant", args.variant, "-q"], check=True)  # fmt: skip
        best: dict[str, dict] = {}
        for r in range(args.runs):
            for kind in ("literal", "opaque"):
                got = match(kind, demo, ref.with_suffix(".png"), tmp / f"{kind}_{r}", args.variant)
                print(f"lookdev kernels {kind:8s} run {r + 1}: {got['distinct_path_kernels']} distinct path kernels, "
                      f"{got['compiled']} kernels compiled in {got['compile_s']:.1f} s, {got['launches']} launches; "
                      f"fit {got['fit_s']:.1f} s, whole command {got['wall_s']:.1f} s")  # fmt: skip
                print(f"lookdev kernels {kind:8s} run {r + 1}: {got['objective']}")
                if kind not in best or got["wall_s"] < best[kind]["wall_s"]:
                    best[kind] = got
    a, b = best["opaque"], best["literal"]
    print(f"lookdev kernels: opaque / literal — path kernels {a['distinct_path_kernels']} / "
          f"{b['distinct_path_kernels']}, compilation {a['compile_s'] / max(b['compile_s'], 1e-9):.2f}x, "
          f"fit {a['fit_s'] / b['fit_s']:.2f}x, whole command {a['wall_s'] / b['wall_s']:.2f}x; {load_line()} at end")  # fmt: skip


if __name__ == "__main__":
    main()
