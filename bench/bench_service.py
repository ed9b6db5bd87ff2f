"""Job service speed, each figure beside a baseline measured in the same run.

Targets (on a 2-core machine):
  * >= 200 job submissions per second (``POST /jobs``, validated and stored durably);
    baseline: ``GET /health`` on the same connections (the server's floor per request);
  * status reads (``GET /jobs/{id}``) p99 <= 20 ms while two renders run;
  * the first progress event <= 2 s after submitting a small render;
  * time to the first visible pixels of a preview of the demo scene (goal <= 3 s): a scene
    new to the running worker, then the same scene again (the worker keeps it), then with the
    sun moved (the trees are kept, the renderer is built again);
  * scene reuse: in a fly-through, frames 2..N start <= 0.5 s after the previous frame ends;
    baseline: the same job on workers that keep no scene (``--worker-scenes 0``).

Each figure is measured against a real ``forest serve`` process on a loopback port, with a
fresh data folder; the demo's latencies with workers at normal CPU priority.  Run: ``.venv/bin/python bench/bench_service.py`` (``--quick`` for fewer
repeats).  Timings are wall-clock on a shared machine: the load average is printed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

FOREST = Path(sys.executable).with_name("forest")
#: Workers at normal priority for the latency figures of the demo (on a machine shared with
#: other work, the default niceness 19 measures the other work as much as the service).
NICE = ("--worker-nice", "0")
ROOT = Path(__file__).resolve().parents[1]

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


def cpu() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines() if Path("/proc/cpuinfo").exists() else []:
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "an unknown CPU"


def load() -> str:
    return f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


class Service:
    def __init__(self, data: Path, workers: int, *extra: str):
        self.data = data
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = open(data.parent / f"serve-{self.port}.log", "ab")
        args = ["--port", str(self.port), "--data", str(data), "--workers", str(workers), "--quiet", *extra]
        self.proc = subprocess.Popen(
            [str(FOREST), "serve", *args], stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True
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


def events(c: httpx.Client, jid: str, t0: float):
    """(seconds since t0, type, data) of a job's events as they arrive, to its end."""
    with c.stream("GET", f"/jobs/{jid}/events", params={"after": 0}, timeout=900) as r:
        kind = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: ") and kind:
                yield time.perf_counter() - t0, kind, json.loads(line[6:])


# -- submissions and status reads ------------------------------------------------------------


def bench_submissions(tmp: Path, n: int, concurrency: int) -> dict:
    """POST /jobs n times from `concurrency` keep-alive connections (no renders), beside GET /health."""
    svc = Service(tmp / "submit", 0)
    body = {"kind": "render", "config": SCENE.format(count=500, width=64, height=48, spp=4)}

    async def run() -> tuple[float, float, list[int]]:
        async with httpx.AsyncClient(
            base_url=svc.url, timeout=60, limits=httpx.Limits(max_connections=concurrency)
        ) as c:
            for _ in range(20):  # warm-up
                await c.post("/jobs", json=body)
                await c.get("/health")
            sem = asyncio.Semaphore(concurrency)

            async def one(i: int) -> int:
                async with sem:
                    return (await c.post("/jobs", json={**body, "name": f"bench {i}"})).status_code

            async def ping() -> int:
                async with sem:
                    return (await c.get("/health")).status_code

            t0 = time.perf_counter()
            await asyncio.gather(*(ping() for _ in range(n)))
            t_health = time.perf_counter() - t0
            t0 = time.perf_counter()
            codes = await asyncio.gather(*(one(i) for i in range(n)))
            return time.perf_counter() - t0, t_health, codes

    try:
        dt, dt_health, codes = asyncio.run(run())
        counts = httpx.get(svc.url + "/jobs").json()["counts"]
    finally:
        svc.stop()
    ok = sum(c == 202 for c in codes)
    return {"accepted": ok, "n": n, "seconds": dt, "per_s": ok / dt, "health_per_s": n / dt_health, **counts}


def bench_status_under_load(tmp: Path, seconds: float) -> dict:
    """Two renders run (one per worker) while one client reads job status back to back."""
    svc = Service(tmp / "load", 2)
    try:
        c = httpx.Client(base_url=svc.url, timeout=30)
        heavy = SCENE.format(count=20000, width=320, height=240, spp=256)
        ids = [c.post("/jobs", json={"kind": "render", "config": heavy}).json()["id"] for _ in range(2)]
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            states = [c.get(f"/jobs/{i}").json() for i in ids]
            if all(s["state"] == "running" and s["tasks"][0].get("passes_done") for s in states):
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
        "p50": statistics.median(lat),
        "p99": lat[int(0.99 * (len(lat) - 1))],
        "max": lat[-1],
        "running": running.count("running"),
    }


def bench_first_progress(tmp: Path, repeats: int) -> dict:
    """Submit a small render and time the first `progress` event on its event stream."""
    svc = Service(tmp / "first", 1)
    small = SCENE.format(count=2000, width=64, height=48, spp=4)
    times = []
    try:
        with httpx.Client(base_url=svc.url, timeout=60) as c:
            for _ in range(repeats):
                t0 = time.perf_counter()
                jid = c.post("/jobs", json={"kind": "render", "config": small}).json()["id"]
                first = next(t for t, kind, _ in events(c, jid, t0) if kind == "progress")
                times.append(first)
                while c.get(f"/jobs/{jid}").json()["state"] not in ("succeeded", "failed", "canceled"):
                    time.sleep(0.05)
    finally:
        svc.stop()
    return {"repeats": repeats, "median": statistics.median(times), "max": max(times)}


# -- the demo: first pixels, scene reuse ---------------------------------------------------------


def demo_text(**replace: str) -> str:
    text = (ROOT / "configs" / "demo.toml").read_text()
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    return text


def sun_moved(text: str, degrees: float = 8.0) -> str:
    """The demo's text with its sun ``degrees`` lower (whatever elevation the demo gives it)."""
    m = re.search(r"sun = \{ elevation = ([0-9.]+)", text)
    assert m, "configs/demo.toml: no sun elevation to move"
    return text[: m.start(1)] + f"{float(m.group(1)) - degrees:.1f}" + text[m.end(1) :]


def first_pixels(c: httpx.Client, text: str, settings: dict) -> dict:
    """Seconds from POST to the first image event, the first finished pass, and the end."""
    t0 = time.perf_counter()
    jid = c.post("/jobs", json={"kind": "render", "config": text, "settings": settings}).json()["id"]
    out = {"image": None, "pass": None, "end": None, "state": None}
    for t, kind, d in events(c, jid, t0):
        if kind == "progress" and d.get("preview") and out["image"] is None:
            out["image"] = t
        if kind == "progress" and d.get("passes_done") and out["pass"] is None:
            out["pass"] = t
        if kind == "state" and d["state"] in ("succeeded", "failed", "canceled"):
            out["end"], out["state"] = t, d["state"]
            break
    return out


def bench_first_pixels(tmp: Path) -> list[tuple[str, dict]]:
    """The demo at preview quality: a new scene, the same scene again, the sun moved."""
    svc = Service(tmp / "pixels", 1, *NICE)
    runs = []
    try:
        with httpx.Client(base_url=svc.url, timeout=60) as c:
            preview = {"preview": True}
            # the service has been up a while: its worker has run something else before
            warm = c.post("/jobs", json={"kind": "render", "config": SCENE.format(count=50, width=8, height=8, spp=1)})
            while c.get(f"/jobs/{warm.json()['id']}").json()["state"] not in ("succeeded", "failed"):
                time.sleep(0.1)
            runs.append(("a new scene", first_pixels(c, demo_text(), preview)))
            runs.append(("same scene again", first_pixels(c, demo_text(), preview)))
            moved = sun_moved(demo_text())
            runs.append(("sun moved", first_pixels(c, moved, preview)))
    finally:
        svc.stop()
    return runs


def frame_gaps(data: Path, jid: str) -> tuple[list[float], list[float]]:
    """Per frame after the first: seconds from the previous task's end to this one's first report
    (its scene in hand) and to its first finished pass, from the store's event times."""
    db = sqlite3.connect(data / "jobs.sqlite3")
    rows = db.execute("SELECT type, data, ts FROM events WHERE job_id=? ORDER BY id", (jid,)).fetchall()
    db.close()
    ended: dict[int, float] = {}
    started: dict[int, float] = {}
    first_pass: dict[int, float] = {}
    for typ, data, ts in rows:
        d = json.loads(data)
        if typ == "task" and d.get("state") == "succeeded":
            ended[d["task"]] = ts
        if typ == "progress" and d.get("frame") is not None:
            started.setdefault(d["task"], ts)
            if d.get("passes_done"):
                first_pass.setdefault(d["task"], ts)
    tasks = sorted(ended)
    start = [started[t] - ended[t - 1] for t in tasks[1:]]
    passes = [first_pass[t] - ended[t - 1] for t in tasks[1:]]
    return start, passes


def bench_scene_reuse(tmp: Path, frames: int) -> list[tuple[str, dict]]:
    """A demo fly-through on one worker that keeps its scene, and on one that keeps none."""
    out = []
    settings = {"frames": f"1-{frames}", "width": 160, "height": 90, "spp": 4, "count": 6000}
    for label, extra in (("keeps the scene", ()), ("keeps no scene (baseline)", ("--worker-scenes", "0"))):
        data = tmp / f"reuse-{len(out)}"
        svc = Service(data, 1, *NICE, *extra)
        try:
            with httpx.Client(base_url=svc.url, timeout=60) as c:
                t0 = time.perf_counter()
                jid = c.post("/jobs", json={"kind": "flythrough", "config": demo_text(), "settings": settings}).json()[
                    "id"
                ]
                for _, kind, d in events(c, jid, t0):
                    if kind == "state" and d["state"] in ("succeeded", "failed", "canceled"):
                        break
                total = time.perf_counter() - t0
                job = c.get(f"/jobs/{jid}").json()
        finally:
            svc.stop()
        start, passes = frame_gaps(data, jid)
        out.append((label, {"state": job["state"], "start": start, "pass": passes, "total": total}))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--submissions", type=int, default=1000)
    ap.add_argument("--concurrency", type=int, default=16)
    ap.add_argument("--load-seconds", type=float, default=8.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--only", default="", help="comma-separated: submit,status,progress,pixels,reuse")
    args = ap.parse_args()
    only = set(filter(None, args.only.split(",")))
    want = lambda name: not only or name in only  # noqa: E731
    print(f"measured on {cpu()}, {os.cpu_count()} cores; load average at start: {os.getloadavg()[0]:.1f}", flush=True)
    with tempfile.TemporaryDirectory(prefix="forest-bench-") as d:
        tmp = Path(d)
        if want("submit"):
            s = bench_submissions(tmp, args.submissions, args.concurrency)
            print(
                f"submissions: {s['accepted']}/{s['n']} accepted in {s['seconds']:.2f} s = {s['per_s']:.0f}/s "
                f"(target >= 200/s: {'ok' if s['per_s'] >= 200 else 'MISSED'}); baseline GET /health "
                f"{s['health_per_s']:.0f}/s on the same connections: submit/health = "
                f"{s['per_s'] / s['health_per_s']:.2f}; {s['queued']} queued in the store",
                flush=True,
            )
        if want("status"):
            lo = bench_status_under_load(tmp, args.load_seconds)
            print(
                f"status reads during two renders: {lo['reads']} reads, p50 {lo['p50']:.1f} ms, "
                f"p99 {lo['p99']:.1f} ms, max {lo['max']:.1f} ms (target p99 <= 20 ms: "
                f"{'ok' if lo['p99'] <= 20 else 'MISSED'}); renders running at the end: {lo['running']}/2",
                flush=True,
            )
        if want("progress"):
            fp = bench_first_progress(tmp, args.repeats)
            print(
                f"first progress event: median {fp['median']:.2f} s, max {fp['max']:.2f} s over "
                f"{fp['repeats']} submits (target <= 2 s: {'ok' if fp['max'] <= 2 else 'MISSED'})",
                flush=True,
            )
        if want("pixels"):
            runs = bench_first_pixels(tmp)
            base = runs[0][1]["image"]
            for label, r in runs:
                print(
                    f"demo preview, {label}: first visible pixels {r['image']:.2f} s (goal <= 3 s: "
                    f"{'ok' if r['image'] <= 3 else 'MISSED'}; {r['image'] / base:.2f}x a new scene), "
                    f"first full pass {r['pass']:.2f} s, done {r['end']:.2f} s ({r['state']})",
                    flush=True,
                )
        if want("reuse"):
            runs = bench_scene_reuse(tmp, args.frames)
            base = statistics.mean(runs[1][1]["start"])
            for label, r in runs:
                worst = max(r["start"])
                print(
                    f"demo fly-through, {args.frames} frames 160x90, worker {label}: frames 2..N start "
                    f"{statistics.mean(r['start']):.2f} s mean / {worst:.2f} s max after the previous frame ends "
                    f"(target <= 0.5 s: {'ok' if worst <= 0.5 else 'MISSED'}; "
                    f"{statistics.mean(r['start']) / base:.2f}x the baseline), first pass "
                    f"{statistics.mean(r['pass']):.2f} s after; whole job {r['total']:.1f} s ({r['state']})",
                    flush=True,
                )
    print(f"load average at end: {load()}", flush=True)


if __name__ == "__main__":
    main()
