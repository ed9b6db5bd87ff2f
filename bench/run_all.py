"""Run every benchmark under bench/ and rebuild the table in bench/RESULTS.md.

    .venv/bin/python bench/run_all.py [--only scatter,export] [--skip render]

Each ``bench_*.py`` prints one figure per line; this script runs them one after
another (never in parallel: the figures are timings), collects their lines and
writes them as one row per benchmark into ``bench/RESULTS.md``, with the
machine they ran on; rows of benchmarks not run this time are kept.  The
README's benchmark section quotes the headline figures by hand.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["scatter", "library", "export", "render", "scenes", "lookdev", "service"]


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = ""
    try:
        kb = int(re.search(r"MemTotal:\s+(\d+)", Path("/proc/meminfo").read_text()).group(1))
        mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, AttributeError):
        pass
    return f"{cpu}, {os.cpu_count()} cores{mem}, {platform.system()} {platform.machine()}, Python {platform.python_version()}"


def run(name: str, timeout: float) -> tuple[list[str], float, int]:
    script = ROOT / "bench" / f"bench_{name}.py"
    t = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
        lines = [l for l in p.stdout.splitlines() if l.strip()]
        rc = p.returncode
        if rc != 0:
            lines.append(f"(failed: exit {rc}: {p.stderr.strip().splitlines()[-1] if p.stderr.strip() else ''})")
    except subprocess.TimeoutExpired:
        lines, rc = [f"(did not finish in {timeout:.0f} s)"], -1
    return lines, time.perf_counter() - t, rc


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="")
    ap.add_argument("--skip", default="")
    ap.add_argument("--timeout", type=float, default=1800)
    args = ap.parse_args()
    names = [n for n in ORDER if (ROOT / "bench" / f"bench_{n}.py").exists()]
    names += sorted(p.stem[6:] for p in (ROOT / "bench").glob("bench_*.py") if p.stem[6:] not in names)
    if args.only:
        names = [n for n in names if n in args.only.split(",")]
    names = [n for n in names if n not in args.skip.split(",")]
    rows = []
    for n in names:
        print(f"== {n}", flush=True)
        lines, _secs, _rc = run(n, args.timeout)
        for l in lines:
            print("  " + l, flush=True)
        rows.append((n, lines))
    # Rows kept from earlier runs may come from another machine: each row names its own.
    table = ["Each row names the machine it was measured on.", "", "| benchmark | figures |", "|---|---|"]
    for n, lines in rows:
        cells = "<br>".join(l.replace("|", "\\|") for l in lines if not l.startswith("machine:"))
        table.append(f"| `bench/bench_{n}.py` | machine: {machine()}<br>{cells} |")
    results = ROOT / "bench" / "RESULTS.md"
    if results.exists():
        # Keep rows for benchmarks not re-run this time.
        kept = [
            l
            for l in results.read_text().splitlines()
            if l.startswith("| `bench/") and not any(f"bench_{n}.py" in l for n, _ in rows)
        ]
        table[4:4] = kept
    text = "\n".join(table)
    (ROOT / "bench" / "RESULTS.md").write_text("# Benchmark results\n\n" + text + "\n")


if __name__ == "__main__":
    main()
