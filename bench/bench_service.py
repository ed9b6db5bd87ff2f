"""Job service speed: submissions per second, status-read latency under load, time to first progress.

Targets (on a 2-core machine):
  * >= 200 job submissions per second (``POST /jobs``, validated and stored durably);
  * status reads (``GET /jobs/{id}``) p99 <= 20 ms while two renders run;
  * the first progress event <= 2 s after submitting a small render.

Each figure is measured against a real ``forest serve`` process on a loopback port,
with a fresh data folder.  Run: ``.venv/bin/python bench/bench_service.py``.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

FOREST = Path(sys.executable).with_name("forest")

SCENE = """
name = "bench"
seed = 5
[terrain]
procedural = {{ size = 300.0, height = 30.0, octaves = 4, resolution = 64 }}
[scatter]
count = {count}
[[species]]
model = "shrub"
percent = 60
[[species]]
model = "broadleaf"
percent = 40
[camera]
position = [0.0, 50.0, -220.0]
target = [0.0, 0.0, 0.0]
fov = 50.0
[render]
width = {width}
height = {height}
spp = {spp}
variant = "scalar_rgb"
subframes = 1
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Service:
    def __init__(self, data: Path, workers: int):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = open(data.parent / f"serve-{self.port}.log", "ab")
        self.proc = subprocess.Popen(
            [str(FOREST), "serve", "--port", str(self.port), "--data", str(data), "--workers", str(workers), "--quiet"],
            stdout=self.log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(self.url + "/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.1)
        raise RuntimeError("forest serve did not start")

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.log.close()


def bench_submissions(tmp: Path, n: int, concurrency: int) -> dict:
    """POST /jobs n times from `concurrency` keep-alive connections; the service runs no renders."""
    svc = Service(tmp / "submit", workers=0)
    body = {"kind": "render", "config": SCENE.format(count=500, width=64, height=48, spp=4)}

    async def run() -> tuple[float, list[int]]:
        async with httpx.AsyncClient(
            base_url=svc.url, timeout=60, limits=httpx.Limits(max_connections=concurrency)
        ) as c:
            for _ in range(20):  # warm-up
                await c.post("/jobs", json=body)
            sem = asyncio.Semaphore(concurrency)

            async def one(i: int) -> int:
                async with sem:
                    r = await c.post("/jobs", json={**body, "name": f"bench {i}"})
                    return r.status_code

            t0 = time.perf_counter()
            codes = await asyncio.gather(*(one(i) for i in range(n)))
            return time.perf_counter() - t0, codes

    try:
        dt, codes = asyncio.run(run())
        counts = httpx.get(svc.url + "/jobs").json()["counts"]
    finally:
        svc.stop()
    ok = sum(c == 202 for c in codes)
    return {"submissions": n, "accepted": ok, "seconds": dt, "per_second": ok / dt, "queued": counts["queued"]}


def bench_status_under_load(tmp: Path, seconds: float) -> dict:
    """Two renders run (one per worker) while one client reads job status back to back."""
    svc = Service(tmp / "load", workers=2)
    try:
        c = httpx.Client(base_url=svc.url, timeout=30)
        heavy = SCENE.format(count=20000, width=320, height=240, spp=256)
        ids = [c.post("/jobs", json={"kind": "render", "config": heavy}).json()["id"] for _ in range(2)]
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            states = [c.get(f"/jobs/{i}").json() for i in ids]
            if all(s["state"] == "running" and s["progress"] > 0 for s in states):
                break
            time.sleep(0.1)
        lat = []
        t_end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < t_end:
            t0 = time.perf_counter()
            r = c.get(f"/jobs/{ids[k % 2]}")
            lat.append((time.perf_counter() - t0) * 1000.0)
            assert r.status_code == 200
            k += 1
        running = [c.get(f"/jobs/{i}").json()["state"] for i in ids]
        for i in ids:
            c.post(f"/jobs/{i}/cancel")
        c.close()
    finally:
        svc.stop()
    lat.sort()
    return {
        "reads": len(lat),
        "p50_ms": statistics.median(lat),
        "p99_ms": lat[int(0.99 * (len(lat) - 1))],
        "max_ms": lat[-1],
        "renders_still_running": running.count("running"),
    }


def bench_first_progress(tmp: Path, repeats: int) -> dict:
    """Submit a small render and time the first `progress` event on its event stream."""
    svc = Service(tmp / "first", workers=1)
    small = SCENE.format(count=2000, width=64, height=48, spp=4)
    times = []
    try:
        with httpx.Client(base_url=svc.url, timeout=60) as c:
            for _ in range(repeats):
                t0 = time.perf_counter()
                jid = c.post("/jobs", json={"kind": "render", "config": small}).json()["id"]
                first = None
                with c.stream("GET", f"/jobs/{jid}/events", params={"after": 0}) as r:
                    kind = None
                    for line in r.iter_lines():
                        if line.startswith("event: "):
                            kind = line[7:]
                        elif line.startswith("data: ") and kind == "progress" and first is None:
                            first = time.perf_counter() - t0
                        elif (
                            line.startswith("data: ")
                            and kind == "state"
                            and json.loads(line[6:])["state"] in ("succeeded", "failed", "canceled")
                        ):
                            break
                times.append(first)
    finally:
        svc.stop()
    return {"repeats": repeats, "median_s": statistics.median(times), "max_s": max(times)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--submissions", type=int, default=1000)
    ap.add_argument("--concurrency", type=int, default=16)
    ap.add_argument("--load-seconds", type=float, default=8.0)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="forest-bench-") as d:
        tmp = Path(d)
        s = bench_submissions(tmp, args.submissions, args.concurrency)
        print(
            f"submissions: {s['accepted']}/{s['submissions']} accepted in {s['seconds']:.2f} s = "
            f"{s['per_second']:.0f}/s (target >= 200/s: {'ok' if s['per_second'] >= 200 else 'MISSED'}); "
            f"{s['queued']} queued in the store",
            flush=True,
        )
        lo = bench_status_under_load(tmp, args.load_seconds)
        print(
            f"status reads during two renders: {lo['reads']} reads, p50 {lo['p50_ms']:.1f} ms, "
            f"p99 {lo['p99_ms']:.1f} ms, max {lo['max_ms']:.1f} ms (target p99 <= 20 ms: "
            f"{'ok' if lo['p99_ms'] <= 20 else 'MISSED'}); renders running at the end: "
            f"{lo['renders_still_running']}/2",
            flush=True,
        )
        fp = bench_first_progress(tmp, args.repeats)
        print(
            f"first progress event: median {fp['median_s']:.2f} s, max {fp['max_s']:.2f} s over "
            f"{fp['repeats']} submits (target <= 2 s: {'ok' if fp['max_s'] <= 2 else 'MISSED'})",
            flush=True,
        )


if __name__ == "__main__":
    main()
