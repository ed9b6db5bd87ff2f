"""Pre-flight: how fast mistakes fail, and how the render memory estimate compares with the measured peak.

1. ``forest render`` into an unwritable place (target: under 1 s), side by side
   with the same render into a writable place — what the mistake cost before
   pre-flight, when the output failed only once the render was done.
2. The bad-input corpus (tests/bad_inputs): time to the one-line error per
   case, against ``forest --version`` (the cost of starting the command).
3. The memory estimate printed before a render against the peak resident
   memory the render reports, at several image sizes, in scalar_rgb and
   llvm_ad_rgb (ratio ≥ 1: the estimate errs on the safe side).

    .venv/bin/python bench/bench_preflight.py
"""

from __future__ import annotations

import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOREST = [str(Path(sys.executable).parent / "forest")]

SCENE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[scatter]
count = {count}
[[species]]
model = "broadleaf"
percent = 100
[camera]
position = [0.0, 30.0, -80.0]
target = [0.0, 0.0, 0.0]
[render]
width = {w}
height = {h}
spp = {spp}
"""


def run(args: list[str], cwd: Path, env: dict | None = None) -> tuple[float, subprocess.CompletedProcess]:
    t0 = time.perf_counter()
    r = subprocess.run([*FOREST, *args], cwd=cwd, capture_output=True, text=True, env=env)
    return time.perf_counter() - t0, r


def load() -> str:
    return f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


def unwritable(tmp: Path) -> None:
    demo = ROOT / "configs" / "demo.toml"
    t_fail, r = run(["render", str(demo), "--preview", "-o", "/sys/forest-bench/frame.exr"], tmp)
    assert r.returncode == 2, r.stderr
    t_ok, r2 = run(["render", str(demo), "--preview", "-q", "-o", str(tmp / "frame.exr")], tmp)
    assert r2.returncode == 0, r2.stderr
    print(f"1. render --preview of configs/demo.toml into /sys (unwritable): fails in {t_fail:.2f} s (target < 1 s)")
    print(f"   {r.stderr.strip()}")
    print(f"   the same render into a writable folder: {t_ok:.1f} s -> the mistake costs {t_fail / t_ok:.3f}x of it")


def corpus(tmp: Path) -> None:
    sys.path.insert(0, str(ROOT / "tests" / "bad_inputs"))
    import make_corpus

    root = tmp / "corpus"
    cases = make_corpus.build(root)
    env = {**os.environ, "XDG_STATE_HOME": str(tmp / "state"), "FOREST_MEMORY_GB": make_corpus.MEMORY_GB}
    times, by_kind, ok = [], {}, 0
    for c in cases:
        meta = json.loads((root / c.name / "case.json").read_text())
        t, r = run(meta["argv"], root / c.name, {**env, **meta["env"]})
        times.append(t)
        by_kind.setdefault(c.kind, []).append(t)
        ok += r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    base = statistics.median(run(["--version"], tmp)[0] for _ in range(3))
    print(
        f"2. bad-input corpus: {ok}/{len(cases)} cases one line + exit 2; time to the error: median "
        f"{statistics.median(times):.2f} s, max {max(times):.2f} s; `forest --version` {base:.2f} s "
        f"(median ratio {statistics.median(times) / base:.1f}x)"
    )
    for kind, ts in sorted(by_kind.items()):
        print(f"   {kind:10s} {len(ts):3d} cases, median {statistics.median(ts):.2f} s, max {max(ts):.2f} s")


def memory(tmp: Path) -> None:
    print("3. render memory: estimate printed before the render vs the peak the render reports")
    print("   variant       size        trees  estimate   measured  estimate/measured")
    for variant, side, count in (
        ("scalar_rgb", 256, 40),
        ("scalar_rgb", 512, 40),
        ("scalar_rgb", 768, 40),
        ("scalar_rgb", 256, 20000),
        ("llvm_ad_rgb", 512, 40),
    ):
        cfg = tmp / f"m_{variant}_{side}_{count}.toml"
        cfg.write_text(SCENE.format(count=count, w=side, h=side, spp=8))
        _, r = run(["render", str(cfg), "--variant", variant, "-o", str(tmp / "m.exr")], tmp)
        if r.returncode != 0:
            print(f"   {variant} {side}: failed: {r.stderr.strip()[-200:]}")
            continue
        est = re.search(r"([\d,]+) trees: about ([\d.]+) (MiB|GiB)", r.stderr)
        peak = re.search(r"peak ([\d.]+) GiB", r.stdout)
        assert est and peak, (r.stderr, r.stdout)
        est_gb = float(est.group(2)) / (1024 if est.group(3) == "MiB" else 1)  # GiB, as the summary's peak
        got = float(peak.group(1))
        trees = int(est.group(1).replace(",", ""))
        print(
            f"   {variant:12s} {side:4d}x{side:<4d} {trees:8,d}  {est_gb:6.2f} GiB {got:6.2f} GiB {est_gb / got:5.2f}"
        )


def main() -> None:
    print(f"pre-flight benchmark; load average at start: {load()}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        unwritable(tmp)
        corpus(tmp)
        memory(tmp)
    print(f"load average at end: {load()}")


if __name__ == "__main__":
    main()
