"""The example scenes end to end: preview and full-quality render times.

    .venv/bin/python bench/bench_scenes.py [--scenes jungle,valley] [--skip-full]

For each scene under configs/ it runs the CLI exactly as the README's gallery does
(`forest render SCENE --preview`), then at the scene's full settings, and prints the
wall time of each whole command (scatter, scene load, render, writing the images).
Target: every preview ≤ 2 minutes on the 2-core machine.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ("jungle", "valley", "flythrough", "city", "ecosystem")


def run(args: list[str]) -> tuple[float, str]:
    exe = Path(sys.executable).parent / "forest"
    t = time.perf_counter()
    p = subprocess.run([str(exe), *args], cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"forest {' '.join(args)} failed: {p.stderr.strip()}")
    summary = next((l for l in p.stdout.splitlines() if l.startswith("rendered")), "")
    return time.perf_counter() - t, summary


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--skip-full", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes.split(","):
            cfg = ROOT / "configs" / f"{name}.toml"
            r = tomllib.loads(cfg.read_text()).get("render", {})
            t, _ = run(["render", str(cfg), "--preview", "-q", "-o", f"{tmp}/{name}_preview.exr"])
            line = f"{name}: preview {t:.0f} s (target ≤ 120 s)"
            if not args.skip_full:
                tf, summary = run(["render", str(cfg), "-o", f"{tmp}/{name}.exr"])
                m = re.search(r"([\d,]+) trees", summary)
                trees = f"{m.group(1)} trees" if m else "?"
                line += (
                    f"; full {r.get('width', 1280)}x{r.get('height', 720)} {r.get('spp', 64)} spp {tf:.0f} s ({trees})"
                )
            print(line, flush=True)


if __name__ == "__main__":
    main()
