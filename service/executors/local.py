"""Local worker processes: one long-lived ``python -m forest.service.worker`` per slot.

A slot's process takes task after task (a :class:`~forest.service.models.TaskOrder` per
line on its stdin) and keeps the scenes it loaded, so the frames of a fly-through after
the first start at once.  A task goes to an idle slot whose worker last ran the same
scene when there is one.  Workers run in their own session at lowered CPU priority;
killing an attempt kills its worker's process group, and a worker idle for ``idle_s``
seconds is let go with the scenes it kept.  Each slot always has a worker process
waiting (``prewarm``): started with the service, and again after one is killed or let
go, so the first task of a job does not wait for Python and Mitsuba to load.

Each slot has a folder under ``root`` (its content-addressed inputs) and a log file
(``worker-<n>.log``: the process's own stdout and stderr).  The worker list shows what each
slot's worker said it renders with (its ``capability`` report: variant, reason, GPU).
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from pydantic import ValidationError

from ..models import Capability, Exit, TaskOrder, parse_report
from ..store import TaskRun
from .base import Executor, WorkerInfo

LOG_LIMIT = 16 * 2**20  # a slot's log starts afresh beyond this size
RESPAWN_S = 5.0  # a waiting worker that died is replaced after this long at the soonest


@dataclass
class _Slot:
    index: int
    proc: subprocess.Popen | None = None
    stdin: IO[bytes] | None = None
    current: tuple[int, int] | None = None
    job_id: str | None = None
    task: int | None = None
    scene: str | None = None
    since: float = field(default_factory=time.time)
    tasks_done: int = 0
    scenes: set[str] = field(default_factory=set)
    spawned: float = 0.0
    capability: Capability | None = None  # what its last worker said it renders with


class LocalExecutor(Executor):
    """``workers`` slots, each a long-lived worker process started on demand.

    ``root``: the slots' folders and logs; ``jobs``: the folder holding the job folders
    (workers write their outputs straight into them).
    """

    name = "local"

    def __init__(
        self,
        workers: int = 1,
        *,
        root: str | Path,
        jobs: str | Path,
        heartbeat_s: float = 1.0,
        nice: int = 19,
        idle_s: float = 600.0,
        scenes: int = 1,
        python: str | None = None,
        prewarm: bool = True,
    ):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.jobs = Path(jobs)
        self.heartbeat_s = heartbeat_s
        self.nice = nice
        self.idle_s = idle_s
        self.scenes = scenes
        self.python = python or sys.executable
        self.q: queue.Queue = queue.Queue()
        self._slots = [_Slot(i) for i in range(max(0, int(workers)))]
        self.lock = threading.Lock()
        self.closed = False
        self.prewarm = prewarm
        self._keep_warm()

    # -- state -----------------------------------------------------------------------
    def capacity(self) -> int:
        """Idle slots."""
        with self.lock:
            return sum(s.current is None for s in self._slots)

    def active(self) -> set[tuple[int, int]]:
        """The attempts the slots run."""
        with self.lock:
            return {s.current for s in self._slots if s.current is not None}

    @property
    def slots(self) -> int:
        """Number of slots (``workers``)."""
        return len(self._slots)

    def workers(self) -> list[WorkerInfo]:
        """Each slot: busy, idle (a live worker) or stopped, with its process, attempt and counts."""
        with self.lock:
            out = []
            for s in self._slots:
                alive = s.proc is not None and s.proc.poll() is None
                out.append(
                    WorkerInfo(
                        name=f"local-{s.index}",
                        executor=self.name,
                        state="busy" if s.current else ("idle" if alive else "stopped"),
                        pid=s.proc.pid if alive and s.proc else None,
                        host=os.uname().nodename,
                        folder=str(self.root / f"slot-{s.index}"),
                        task_id=s.current[0] if s.current else None,
                        attempt=s.current[1] if s.current else None,
                        job_id=s.job_id if s.current else None,
                        task=s.task if s.current else None,
                        since=s.since,
                        tasks_done=s.tasks_done,
                        scenes=len(s.scenes) if alive else 0,
                        **_capability(s.capability),
                    )
                )
            return out

    def pid(self, task_id: int, attempt: int) -> int | None:
        """Process id of the worker running this attempt (None when no slot runs it)."""
        with self.lock:
            for s in self._slots:
                if s.current == (task_id, attempt) and s.proc is not None:
                    return s.proc.pid
        return None

    # -- starting ---------------------------------------------------------------------
    def _pick(self, scene: str) -> _Slot | None:
        idle = [s for s in self._slots if s.current is None]
        warm = [s for s in idle if s.proc is not None and s.stdin is not None and s.proc.poll() is None]
        for group in ([s for s in warm if scene in s.scenes], warm, idle):
            if group:
                return group[0]
        return None

    def _spawn(self, slot: _Slot) -> None:
        folder = self.root / f"slot-{slot.index}"
        folder.mkdir(parents=True, exist_ok=True)
        log_path = self.root / f"worker-{slot.index}.log"
        if log_path.exists() and log_path.stat().st_size > LOG_LIMIT:
            log_path.unlink()
        log = open(log_path, "ab", buffering=0)
        r, w = os.pipe()
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")
        env["FOREST_WORKER_NICE"] = str(self.nice)
        env["FOREST_WORKER_SCENES"] = str(self.scenes)
        try:
            proc = subprocess.Popen(
                [self.python, "-m", "forest.service.worker", str(w), str(folder)],
                stdin=subprocess.PIPE,
                stdout=log,
                stderr=subprocess.STDOUT,
                pass_fds=(w,),
                cwd=folder,
                env=env,
                start_new_session=True,
            )
        finally:
            os.close(w)
            log.close()
        slot.proc, slot.stdin, slot.scenes, slot.spawned = proc, proc.stdin, set(), time.monotonic()
        threading.Thread(target=self._read, args=(slot, proc, r), daemon=True, name=f"worker-{slot.index}").start()

    def start(self, run: TaskRun) -> str:
        """Send the attempt to an idle slot, preferring a live worker that has the scene loaded; returns ``pid:<n>``."""
        with self.lock:
            slot = self._pick(run.spec.scene_key)
            if slot is None:
                raise RuntimeError("no free worker slot")
            if slot.proc is None or slot.stdin is None or slot.proc.poll() is not None:
                self._spawn(slot)
            assert slot.proc is not None and slot.stdin is not None
            slot.current = (run.task_id, run.attempt)
            slot.job_id, slot.task, slot.since = run.job_id, run.index, time.time()
            slot.scenes.add(run.spec.scene_key)
            proc, stdin = slot.proc, slot.stdin
        job_dir = self.jobs / run.job_id
        order = TaskOrder(
            task_id=run.task_id, attempt=run.attempt, spec=run.spec, job_dir=str(job_dir), heartbeat_s=self.heartbeat_s
        )
        try:
            stdin.write((order.model_dump_json() + "\n").encode())
            stdin.flush()
        except (BrokenPipeError, OSError, ValueError):
            pass  # it died: its reader reports the exit
        return f"pid:{proc.pid}"

    def _read(self, slot: _Slot, proc: subprocess.Popen, fd: int) -> None:
        with os.fdopen(fd, "rb") as f:
            for line in f:
                try:
                    report = parse_report(line)
                except ValidationError:
                    try:
                        cap = Capability.model_validate_json(line)
                    except ValidationError:
                        continue
                    with self.lock:
                        if slot.proc is proc:
                            slot.capability = cap
                    continue
                key = (report.task_id, report.attempt)
                finished = False
                with self.lock:
                    if slot.current != key:
                        continue  # not the attempt this slot runs: stale
                    if report.type in ("done", "error"):
                        slot.current, slot.since = None, time.time()
                        slot.tasks_done += 1
                        finished = True
                self.q.put(report)
                if finished:
                    self.q.put(Exit(task_id=key[0], attempt=key[1], code=0))
        code = proc.wait()
        with self.lock:
            lost = slot.current if slot.proc is proc else None
            if slot.proc is proc:
                slot.proc = slot.stdin = None
                slot.current, slot.since = None, time.time()
        if lost is not None:
            self.q.put(Exit(task_id=lost[0], attempt=lost[1], code=code))

    # -- the dispatcher's loop ----------------------------------------------------------
    def poll(self, timeout: float) -> list[Any]:
        """Reports within ``timeout`` seconds (all queued once one arrives); then idle workers go and slots prewarm."""
        out = []
        try:
            out.append(self.q.get(timeout=timeout))
            while True:
                out.append(self.q.get_nowait())
        except queue.Empty:
            pass
        self._let_idle_go()
        self._keep_warm()
        return out

    def _keep_warm(self) -> None:
        """Every slot has a worker that has imported the renderer, waiting for its first task."""
        if not self.prewarm or self.closed:
            return
        with self.lock:
            now = time.monotonic()
            for s in self._slots:
                if s.proc is None and s.current is None and now - s.spawned > RESPAWN_S:
                    self._spawn(s)

    def _let_idle_go(self) -> None:
        now = time.time()
        with self.lock:
            for s in self._slots:
                if s.current is None and s.proc is not None and s.stdin is not None and now - s.since > self.idle_s:
                    try:
                        s.stdin.close()  # end-of-file: the worker exits
                    except OSError:
                        pass
                    s.stdin = None

    def kill(self, task_id: int, attempt: int) -> None:
        """Kill the process group of the worker running this attempt; its reader then reports the exit."""
        with self.lock:
            proc = next((s.proc for s in self._slots if s.current == (task_id, attempt)), None)
        if proc is not None:
            _kill_group(proc)

    def close(self) -> None:
        """Kill every worker's process group and wait up to 5 s for them to end."""
        self.closed = True
        with self.lock:
            procs = [s.proc for s in self._slots if s.proc is not None]
        for p in procs:
            _kill_group(p)
        deadline = time.monotonic() + 5.0
        for p in procs:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass


def _capability(cap: Capability | None) -> dict[str, Any]:
    """The :class:`WorkerInfo` fields of a worker's capability report (none before it came)."""
    return cap.model_dump(include={"variant", "variant_reason", "gpu", "gpu_memory_mib"}) if cap is not None else {}


def _kill_group(proc: subprocess.Popen) -> None:
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        try:
            proc.kill()
        except ProcessLookupError:
            pass
