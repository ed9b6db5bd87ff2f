"""Helpers shared by the job-service tests (no tests here).

A tiny scene (procedural terrain, a few hundred shrubs, 32×24 pixels, 2 spp,
``scalar_rgb``) keeps every real render well under a second once a worker has loaded
it; servers run on loopback ports picked by the OS, either in a thread (uvicorn) or as
a ``forest serve`` process.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
FOREST = Path(sys.executable).with_name("forest")

TINY = """
name = "tiny"
seed = 3
[terrain]
procedural = {{ size = 200.0, height = 20.0, octaves = 3, resolution = 32 }}
[scatter]
count = {count}
[[species]]
model = "shrub"
percent = 100
[camera]
position = [0.0, 40.0, -150.0]
target = [0.0, 0.0, 0.0]
fov = 50.0
keys = [
  {{ frame = 1, position = [0.0, 40.0, -150.0], target = [0.0, 0.0, 0.0] }},
  {{ frame = 8, position = [30.0, 35.0, -120.0], target = [0.0, 0.0, 0.0] }},
]
[render]
width = 32
height = 24
spp = 2
variant = "scalar_rgb"
subframes = 1
"""


def tiny_config(count: int = 300) -> str:
    return TINY.format(count=count)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerThread:
    """Run an ASGI app with uvicorn in a background thread on a free loopback port."""

    def __init__(self, app):
        import uvicorn

        self.port = free_port()
        self.server = uvicorn.Server(
            uvicorn.Config(
                app,
                host="127.0.0.1",
                port=self.port,
                log_level="warning",
                access_log=False,
                timeout_graceful_shutdown=2,
            )
        )
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.url = f"http://127.0.0.1:{self.port}"

    def __enter__(self) -> ServerThread:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("server did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=20)


class ServeProcess:
    """``forest serve`` as a child process (so it can be killed like a real service)."""

    def __init__(self, data: Path, *args: str, port: int | None = None):
        self.port = port or free_port()
        self.data = data
        self.args = args
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self) -> ServeProcess:
        self.log = open(self.data.parent / f"serve-{self.port}.log", "ab")
        self.proc = subprocess.Popen(
            [str(FOREST), "serve", "--port", str(self.port), "--data", str(self.data), "--quiet", *self.args],
            stdout=self.log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"forest serve exited with {self.proc.returncode}")
            try:
                if httpx.get(self.url + "/health", timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError("forest serve did not answer")

    def kill(self) -> None:
        """SIGKILL the service process alone (its workers notice and exit by themselves)."""
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self.log.close()


def wait_job(
    client: httpx.Client, job_id: str, states=("succeeded", "failed", "canceled"), timeout: float = 90.0
) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        job = client.get(f"/jobs/{job_id}").json()
        if job["state"] in states:
            return job
        if time.monotonic() > deadline:
            raise AssertionError(f"job {job_id} still {job['state']} after {timeout} s: {job}")
        time.sleep(0.1)


def wait_for(predicate, timeout: float = 60.0, step: float = 0.05):
    deadline = time.monotonic() + timeout
    while True:
        v = predicate()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(step)


def stream_events(client: httpx.Client, job_id: str, after: int = 0, timeout: float = 90.0):
    """A job's event stream as it arrives: yields ``(type, data)`` until the stream ends."""
    with client.stream("GET", f"/jobs/{job_id}/events", params={"after": after}, timeout=timeout) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        kind, data = None, None
        for line in r.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: "):
                data = json.loads(line[6:])
            elif line == "" and kind is not None:
                yield kind, data
                kind, data = None, None


def read_events(client: httpx.Client, job_id: str, after: int = 0, timeout: float = 90.0) -> list[tuple[str, dict]]:
    """Consume a job's event stream to its end; return ``[(type, data), …]``."""
    return list(stream_events(client, job_id, after, timeout))


def file_stamps(folder: Path, pattern: str = "*") -> dict[str, tuple[int, int]]:
    """``{name: (inode, mtime_ns)}`` of the files in a folder: a file written again changes both."""
    out = {}
    for p in sorted(folder.glob(pattern)):
        st = p.stat()
        out[p.name] = (st.st_ino, st.st_mtime_ns)
    return out


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is not alive
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False
