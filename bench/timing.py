"""Timing shared by the benchmarks that compare renders of the same scene with and without a feature.

    from timing import best_of, cpu_seconds   # a bench_*.py run as a script has bench/ on sys.path

:func:`best_of` runs each variant once to warm up (the first run compiles its kernels), then
alternates them ``rounds`` times, so a busy machine slows every variant alike, and keeps each
variant's fastest run by CPU seconds.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def cpu_seconds() -> float:
    """User + system CPU seconds of this process so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def best_of(
    runs: Mapping[Any, Callable[[], Any]], rounds: int = 3
) -> tuple[dict[Any, Any], dict[Any, tuple[float, float]]]:
    """({key: the warm-up run's result}, {key: (wall s, CPU s) of its fastest timed run by CPU})."""
    first = {key: run() for key, run in runs.items()}
    best: dict[Any, tuple[float, float]] = {}
    for _ in range(rounds):
        for key, run in runs.items():
            t0, c0 = time.perf_counter(), cpu_seconds()
            run()
            took = (time.perf_counter() - t0, cpu_seconds() - c0)
            if key not in best or took[1] < best[key][1]:
                best[key] = took
    return first, best


def versus(run: tuple[float, float], base: tuple[float, float], what: str) -> str:
    """One variant's (wall s, CPU s) from :func:`best_of` against the baseline's:
    ``"W s wall, C CPU-s (Rx CPU, Rx wall of WHAT)"``."""
    wall, cpu = run
    return f"{wall:6.2f} s wall, {cpu:6.2f} CPU-s ({cpu / base[1]:.2f}x CPU, {wall / base[0]:.2f}x wall of {what})"


def children_cpu_seconds() -> float:
    """User + system CPU seconds of this process's finished children so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def forest_render(
    config: Path, out: Path, sets: Sequence[str], width: int, height: int, spp: int
) -> tuple[float, float, subprocess.CompletedProcess[str]]:
    """One whole ``forest render`` of ``config`` to ``out`` with ``--set`` ``sets`` at that size and samples:
    (wall s, CPU s of the command, the finished process)."""
    cmd = [str(ROOT / ".venv" / "bin" / "forest"), "render", str(config), "-o", str(out)]
    for s in [*sets, f"render.width={width}", f"render.height={height}", f"render.spp={spp}"]:
        cmd += ["--set", s]
    t0, c0 = time.perf_counter(), children_cpu_seconds()
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, children_cpu_seconds() - c0, done


def alternate_renders(
    paths: Mapping[str, Path], folder: Path, sets: Sequence[str], width: int, height: int, spp: int, runs: int
) -> tuple[dict[str, tuple[float, float]], dict[str, str]]:
    """Render each config of ``paths`` to ``folder/NAME.exr`` ``runs`` times, alternating (:func:`forest_render`):
    ({name: (wall s, CPU s) of its fastest run by CPU}, {name: its last run's stdout + stderr})."""
    best: dict[str, tuple[float, float]] = {}
    summary: dict[str, str] = {}
    for _ in range(runs):
        for name, path in paths.items():
            wall, cpu, done = forest_render(path, folder / f"{name}.exr", sets, width, height, spp)
            summary[name] = done.stdout + done.stderr
            if name not in best or cpu < best[name][1]:
                best[name] = (wall, cpu)
    return best, summary


def tree_count(summary: str) -> str:
    """The tree count of ``forest render``'s summary line ('?' when it has none)."""
    import re

    m = re.search(r"([\d,]+) trees", summary)
    return m.group(1) if m else "?"


def keep_renders(folder: Path, names: Sequence[str], keep: Path | None, prefix: str) -> None:
    """Copy each ``folder/NAME.exr`` and ``.png`` to ``keep/PREFIX_NAME.*`` (nothing when ``keep`` is None)."""
    if keep is None:
        return
    keep.mkdir(parents=True, exist_ok=True)
    for name in names:
        for ext in (".exr", ".png"):
            src = folder / f"{name}{ext}"
            if src.exists():
                (keep / f"{prefix}_{name}{ext}").write_bytes(src.read_bytes())


def render_arguments(description: str, size: str) -> argparse.Namespace:
    """``--size WxH`` (default ``size``), ``--spp``, ``--runs``, ``--keep DIR``: the options of a bench that renders a
    scene with and without a feature through :func:`forest_render`."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--size", default=size)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--keep", type=Path, default=None, help="Keep the renders here.")
    return ap.parse_args()


def load_line() -> str:
    """``load average a / b / c``: the machine's 1, 5 and 15-minute load averages."""
    a, b, c = os.getloadavg()
    return f"load average {a:.1f} / {b:.1f} / {c:.1f}"
