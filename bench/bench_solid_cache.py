"""Solid leaf cards computed against read from forest's cache folder (``forest.render.path.solid``, "Cache").

    .venv/bin/python bench/bench_solid_cache.py [--config configs/demo.toml] [--runs 2]

Two measurements, each against its baseline in the same run:

* the step alone, in this process: every library part the config's scene draws with solid cards
  (:func:`forest.render.path.solid.solid_part` over each species' individuals and levels), computed
  (an empty cache folder; the baseline) and then read back from the cache (the in-process memo
  cleared first, as a new process starts), best of ``--runs``; the arrays must be identical;
* the whole command: ``forest render CONFIG --preview`` in a child process with an empty cache folder
  and then with the one it filled, alternating, ``--runs`` times: the scene load from the summary
  line, and whether the EXRs are the same bytes.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def parts(config_path: Path) -> list[tuple[object, object]]:
    """(mesh, part) of every leaf part of every species, individual and level the scene could draw."""
    from forest.config import load_config
    from forest.library.mesh import read_ply
    from forest.scene import load_scene

    scene = load_scene(load_config(config_path))
    out = []
    for individuals in scene.individuals:
        for sp in individuals:
            for lod in sp.lods:
                for part in lod.parts:
                    if part.kind == "leaf":
                        out.append((read_ply(part.path), part))
    return out


def step(config_path: Path, runs: int) -> None:
    import forest.render.path.solid as solid

    todo = parts(config_path)
    best = {"computed": float("inf"), "read": float("inf")}
    first: list = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="forest-solid-") as d:
            os.environ["FOREST_CACHE_DIR"] = d
            for name in ("computed", "read"):
                solid._solid_file.cache_clear()
                t0 = time.perf_counter()
                got = [solid.solid_part(mesh, part)[0] for mesh, part in todo]
                best[name] = min(best[name], time.perf_counter() - t0)
                if not first:
                    first = got
                same = all(np.array_equal(a.vertices, b.vertices)
                           and np.array_equal(getattr(a, "rgb", 0), getattr(b, "rgb", 0))
                           for a, b in zip(first, got))  # fmt: skip
                assert same, "the cache gave other arrays"
    n = sum(1 for m in first if isinstance(m, solid.SolidMesh))
    print(f"solid cache step: {n} parts drawn solid: computed {best['computed']:.2f} s, read from the cache "
          f"{best['read']:.2f} s — computed / read = {best['computed'] / max(best['read'], 1e-9):.1f}x; "
          "identical arrays")  # fmt: skip


def command(config_path: Path, runs: int) -> None:
    load = re.compile(r"load ([\d.]+) s, render ([\d.]+) s")
    exe = [str(Path(sys.executable).parent / "forest")]
    loads: dict[str, list[float]] = {"empty cache": [], "warm cache": []}
    same = True
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="forest-solid-") as d:
            env = {**os.environ, "FOREST_CACHE_DIR": str(Path(d) / "cache"), "FOREST_PROGRESS": "none"}
            outs = []
            for name in loads:
                exr = Path(d) / f"{name.split()[0]}.exr"
                r = subprocess.run([*exe, "render", str(config_path), "--preview", "-o", str(exr),
                                    "--variant", "llvm_ad_rgb"], capture_output=True, text=True, env=env)  # fmt: skip
                m = load.search(r.stdout + r.stderr)
                if r.returncode != 0 or not m:
                    raise SystemExit(f"render failed: {(r.stdout + r.stderr)[-800:]}")
                loads[name].append(float(m.group(1)))
                outs.append(exr.read_bytes())
            same &= outs[0] == outs[1]
    e, w = min(loads["empty cache"]), min(loads["warm cache"])
    print(f"solid cache command: forest render {config_path.name} --preview, scene load (best of {runs}): "
          f"empty cache {e:.1f} s, warm cache {w:.1f} s — {e - w:.1f} s less, {e / max(w, 1e-9):.2f}x; "
          f"EXRs {'identical' if same else 'DIFFERENT'}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "demo.toml"))
    ap.add_argument("--runs", type=int, default=2)
    a = ap.parse_args()
    print(f"solid cache: {a.config}, load average {os.getloadavg()[0]:.1f}")
    step(Path(a.config), a.runs)
    command(Path(a.config), a.runs)


if __name__ == "__main__":
    main()
