"""Executors: where task attempts run.

Both backends implement the same small interface the dispatcher drives:

``capacity()``            how many more attempts may start now;
``start(run)``            start one attempt (:class:`forest.service.store.TaskRun`);
``poll(timeout)``         reports since the last call, as dicts with ``task_id``,
                          ``attempt`` and ``type`` (``heartbeat`` | ``progress`` | ``log`` |
                          ``done`` | ``error`` | ``exit``);
``kill(task_id, attempt)`` stop an attempt now (cancel, lost lease);
``close()``               stop everything.

An ``exit`` report follows every attempt; an attempt whose ``exit`` comes without a
``done`` or ``error`` before it has lost its worker.

* :class:`LocalExecutor` runs each attempt in its own process (``python -m
  forest.service.worker``) in a new session, so a kill takes the whole process group.
* :class:`RayExecutor` runs each attempt as a Ray task with CPU/GPU resource requests
  (``cuda_ad_rgb`` jobs ask for a GPU, so Ray places them on GPU nodes); progress and
  heartbeats travel through a small reporter actor.  The data folder must be visible
  at the same path on every node (a shared file system).
"""

from __future__ import annotations

import abc
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from .store import TaskRun


class Executor(abc.ABC):
    """Where task attempts run.  The dispatcher is the only caller, from one thread."""

    name = "base"

    @abc.abstractmethod
    def capacity(self) -> int:
        """How many attempts may run at once."""

    @abc.abstractmethod
    def start(self, run: TaskRun) -> str:
        """Start one attempt; return a description of where it runs (for the job log)."""

    @abc.abstractmethod
    def poll(self, timeout: float) -> list[dict]:
        """Reports (progress, heartbeat, result, exit) received within ``timeout`` seconds."""

    @abc.abstractmethod
    def kill(self, task_id: int, attempt: int) -> None:
        """Stop an attempt (cancel or lost lease); a no-op if it already ended."""

    @abc.abstractmethod
    def active(self) -> set[tuple[int, int]]:
        """The (task id, attempt) pairs still running."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop every attempt and release resources."""


class LocalExecutor(Executor):
    """A pool of ``workers`` slots; each attempt is one child process."""

    name = "local"

    def __init__(self, workers: int = 1, *, heartbeat_s: float = 1.0, nice: int = 19, python: str | None = None):
        self.workers = max(0, int(workers))
        self.heartbeat_s = heartbeat_s
        self.nice = nice
        self.python = python or sys.executable
        self.q: queue.Queue = queue.Queue()
        self.procs: dict[tuple[int, int], subprocess.Popen] = {}
        self.lock = threading.Lock()
        self.closed = False

    def capacity(self) -> int:
        with self.lock:
            return self.workers - len(self.procs)

    def active(self) -> set[tuple[int, int]]:
        with self.lock:
            return set(self.procs)

    def start(self, run: TaskRun) -> str:
        job_dir = Path(run.spec["job_dir"])
        job_dir.mkdir(parents=True, exist_ok=True)
        log = open(job_dir / "job.log", "ab", buffering=0)
        r, w = os.pipe()
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env["PYTHONPATH"] = os.pathsep.join(
            filter(None, [str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])
        )
        try:
            proc = subprocess.Popen(
                [self.python, "-m", "forest.service.worker", str(w)],
                stdin=subprocess.PIPE,
                stdout=log,
                stderr=subprocess.STDOUT,
                pass_fds=(w,),
                cwd=job_dir,
                env=env,
                start_new_session=True,
            )
        finally:
            os.close(w)
            log.close()
        key = (run.task_id, run.attempt)
        with self.lock:
            self.procs[key] = proc
        msg = {
            "task_id": run.task_id,
            "attempt": run.attempt,
            "spec": run.spec,
            "heartbeat_s": self.heartbeat_s,
            "nice": self.nice,
        }
        try:
            proc.stdin.write((json.dumps(msg) + "\n").encode())
            proc.stdin.flush()
        except (BrokenPipeError, OSError):
            pass  # it died at once; the reader reports the exit
        threading.Thread(
            target=self._read, args=(key, proc, r), daemon=True, name=f"worker-{run.task_id}.{run.attempt}"
        ).start()
        return f"pid:{proc.pid}"

    def _read(self, key: tuple[int, int], proc: subprocess.Popen, fd: int) -> None:
        task_id, attempt = key
        with os.fdopen(fd, "r", encoding="utf-8", errors="replace") as f:
            for line in f:
                try:
                    msg = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if msg.get("task_id") != task_id or msg.get("attempt") != attempt:
                    continue
                self.q.put(msg)
        code = proc.wait()
        try:
            proc.stdin.close()
        except OSError:
            pass
        with self.lock:
            self.procs.pop(key, None)
        self.q.put({"task_id": task_id, "attempt": attempt, "type": "exit", "code": code})

    def poll(self, timeout: float) -> list[dict]:
        out = []
        try:
            out.append(self.q.get(timeout=timeout))
            while True:
                out.append(self.q.get_nowait())
        except queue.Empty:
            pass
        return out

    def kill(self, task_id: int, attempt: int) -> None:
        with self.lock:
            proc = self.procs.get((task_id, attempt))
        if proc is None or proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            try:
                proc.kill()
            except ProcessLookupError:
                pass

    def pid(self, task_id: int, attempt: int) -> int | None:
        with self.lock:
            p = self.procs.get((task_id, attempt))
        return p.pid if p else None

    def close(self) -> None:
        self.closed = True
        for key in list(self.active()):
            self.kill(*key)
        deadline = time.monotonic() + 5.0
        while self.active() and time.monotonic() < deadline:
            time.sleep(0.02)


# ---------------------------------------------------------------------------
# Ray
# ---------------------------------------------------------------------------


def _ray_task_body(spec: dict, task_id: int, attempt: int, reporter, heartbeat_s: float) -> dict:
    """Runs inside a Ray worker: the same :func:`forest.service.runner.execute` as a local worker."""
    from forest.errors import ForestError
    from forest.service.runner import execute

    stop = threading.Event()

    def send(type_: str, payload: dict | None = None) -> None:
        reporter.put.remote({"task_id": task_id, "attempt": attempt, "type": type_, **(payload or {})})

    def beat() -> None:
        while not stop.is_set():
            send("heartbeat")
            stop.wait(heartbeat_s)

    threading.Thread(target=beat, daemon=True).start()
    try:
        result = execute(spec, send)
        return {"type": "done", "result": result}
    except ForestError as e:
        return {"type": "error", "error": str(e), "user": True}
    except Exception as e:
        return {"type": "error", "error": f"{type(e).__name__}: {e}", "user": False}
    finally:
        stop.set()


class RayExecutor(Executor):
    """Attempts as Ray tasks; ``slots`` bounds how many are in flight at once."""

    name = "ray"

    def __init__(
        self, address: str | None = None, *, slots: int = 1, heartbeat_s: float = 1.0, init_kwargs: dict | None = None
    ):
        try:
            import ray
        except ImportError:
            from forest.errors import ForestError

            raise ForestError("--executor ray: the ray package is not installed (pip install 'forest[ray]')") from None
        self.ray = ray
        self.slots = max(0, int(slots))
        self.heartbeat_s = heartbeat_s
        self.started_ray = False
        if not ray.is_initialized():
            kwargs = dict(init_kwargs or {})
            kwargs.setdefault("include_dashboard", False)
            kwargs.setdefault("logging_level", "warning")
            kwargs.setdefault("log_to_driver", False)
            if address:
                kwargs.pop("num_cpus", None)
                kwargs.pop("num_gpus", None)
                kwargs.pop("object_store_memory", None)
                kwargs.pop("include_dashboard", None)
            ray.init(address=address, **kwargs)
            self.started_ray = True

        @ray.remote(num_cpus=0)
        class Reporter:
            def __init__(self):
                self.items: list[dict] = []

            def put(self, item: dict) -> None:
                self.items.append(item)

            def drain(self) -> list[dict]:
                items, self.items = self.items, []
                return items

        self.reporter = Reporter.remote()
        self.remote_fn = ray.remote(max_retries=0)(_ray_task_body)
        self.refs: dict[tuple[int, int], object] = {}
        self.lock = threading.Lock()

    def capacity(self) -> int:
        with self.lock:
            return self.slots - len(self.refs)

    def active(self) -> set[tuple[int, int]]:
        with self.lock:
            return set(self.refs)

    @staticmethod
    def resources(spec: dict) -> dict:
        """Ray resource request: a GPU for ``cuda_*`` variants, ``cpus`` CPUs (default 1)."""
        res = dict(spec.get("resources") or {})
        gpus = float(res.get("gpus", 1.0 if str(spec.get("variant") or "").startswith("cuda") else 0.0))
        cpus = float(res.get("cpus", 1.0))
        return {"num_cpus": cpus, "num_gpus": gpus}

    def start(self, run: TaskRun) -> str:
        opts = self.resources(run.spec)
        ref = self.remote_fn.options(**opts).remote(run.spec, run.task_id, run.attempt, self.reporter, self.heartbeat_s)
        with self.lock:
            self.refs[(run.task_id, run.attempt)] = ref
        return f"ray:{ref.task_id().hex()}"

    def poll(self, timeout: float) -> list[dict]:
        ray = self.ray
        done: list[dict] = []
        with self.lock:
            items = list(self.refs.items())
        if items:
            ready, _ = ray.wait([r for _, r in items], num_returns=len(items), timeout=0)
            ready_set = set(ready)
            for key, ref in items:
                if ref not in ready_set:
                    continue
                task_id, attempt = key
                try:
                    res = ray.get(ref)
                    done.append({"task_id": task_id, "attempt": attempt, **res})
                    code = 0
                except Exception as e:
                    done.append(
                        {
                            "task_id": task_id,
                            "attempt": attempt,
                            "type": "log",
                            "line": f"ray task ended: {type(e).__name__}",
                        }
                    )
                    code = -9
                with self.lock:
                    self.refs.pop(key, None)
                done.append({"task_id": task_id, "attempt": attempt, "type": "exit", "code": code})
        out: list[dict] = []
        if items:
            try:
                # Reports drained after the finished refs were collected, and put before them.
                out.extend(ray.get(self.reporter.drain.remote(), timeout=max(timeout, 1.0)))
            except Exception:
                pass
        out.extend(done)
        if not out:
            time.sleep(min(timeout, 0.05))
        return out

    def kill(self, task_id: int, attempt: int) -> None:
        with self.lock:
            ref = self.refs.get((task_id, attempt))
        if ref is not None:
            try:
                self.ray.cancel(ref, force=True)
            except Exception:
                pass

    def close(self) -> None:
        for key in list(self.active()):
            self.kill(*key)
        if self.started_ray:
            try:
                self.ray.shutdown()
            except Exception:
                pass
