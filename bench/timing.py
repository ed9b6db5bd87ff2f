"""Timing shared by the benchmarks that compare renders of the same scene with and without a feature.

    from timing import best_of, cpu_seconds   # a bench_*.py run as a script has bench/ on sys.path

:func:`best_of` runs each variant once to warm up (the first run compiles its kernels), then
alternates them ``rounds`` times, so a busy machine slows every variant alike, and keeps each
variant's fastest run by CPU seconds.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Mapping
from typing import Any


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
