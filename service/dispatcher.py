"""The dispatcher: one thread that moves work between the store and an executor.

Each tick (``tick_s``, 50 ms by default) it

1. applies the executor's reports — heartbeats renew leases; files a worker shipped
   (it shares no disk with the service) are written into the job folder first; progress,
   finished frames and log lines are recorded; ``done``/``error`` finish the attempt (an
   error about a library parameter is named by the request's JSON field); an ``exit``
   without either means the worker was lost (requeue within the retry limit).  Every
   report names its attempt; the store ignores stale ones, and the dispatcher kills a
   worker whose attempt turns out stale (it lost its lease and the task moved on);
2. every ``housekeeping_s``: kills and requeues attempts whose lease expired (no
   heartbeat for ``lease_s``), and stops the running attempts of canceled jobs; every
   ``retention.interval_s``: applies the retention policy (:mod:`.retention`) in a thread
   of its own;
3. starts queued tasks (highest priority first, then oldest) while the executor has
   room, telling each frame task which of its frames are already on disk.

Each job folder gets a log (``job.log``) and one per task (``logs/task-NNNN.log``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import socket
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from .assets import DataDir
from .executors import Executor
from .models import FRAME_KINDS, Done, Exit, Failed, FrameDone, Heartbeat, Log, Progress, TaskSpec
from .retention import Retention, sweep, write_manifest
from .store import TERMINAL, Store, TaskRun
from .transfer import write_shipped
from .views import field_name

log = logging.getLogger("forest.service")


def frames_on_disk(job_dir: Path, spec: TaskSpec) -> list[int]:
    """Frames of a frame task whose EXR and PNG are in the job folder."""
    from .runner import frame_files

    if spec.kind not in FRAME_KINDS:
        return []
    return [f for f in spec.frames or (1,) if all((job_dir / p).is_file() for p in frame_files(spec, f))]


class Dispatcher:
    """The dispatcher thread over ``store`` and ``executor`` (module docstring); while ``paused`` it starts no task."""

    def __init__(
        self,
        store: Store,
        executor: Executor,
        datadir: DataDir,
        *,
        lease_s: float = 15.0,
        tick_s: float = 0.05,
        housekeeping_s: float = 0.25,
        retention: Retention | None = None,
    ):
        self.store = store
        self.executor = executor
        self.datadir = datadir
        self.lease_s = lease_s
        self.tick_s = tick_s
        self.housekeeping_s = housekeeping_s
        self.retention = retention or Retention()
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self.jobs: dict[tuple[int, int], tuple[str, int, str]] = {}  # (task, attempt) → (job id, index, kind)
        self.canceling: set[tuple[int, int]] = set()
        self.paused = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.errors = 0
        self.last_sweep = 0.0
        self._sweeping = threading.Thread()  # the retention sweep (never blocks the dispatcher)

    # -- lifecycle -------------------------------------------------------------
    def start(self) -> None:
        """Start the dispatcher thread (once)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="dispatcher", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the thread (waiting up to 10 s) and close the executor."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        self.executor.close()

    def _run(self) -> None:
        last_house = 0.0
        while not self._stop.is_set():
            try:
                for msg in self.executor.poll(self.tick_s):
                    self.handle(msg)
                now = time.monotonic()
                if now - last_house >= self.housekeeping_s:
                    last_house = now
                    self.housekeeping()
                if now - self.last_sweep >= self.retention.interval_s and not self._sweeping.is_alive():
                    self.last_sweep = now
                    self._sweeping = threading.Thread(target=self._sweep, name="retention", daemon=True)
                    self._sweeping.start()
                if not self.paused:
                    self.fill()
            except Exception:
                self.errors += 1
                log.exception("dispatcher tick failed")
                time.sleep(0.2)

    def _sweep(self) -> None:
        try:
            sweep(self.store, self.datadir, self.retention)
        except Exception:
            log.exception("retention sweep failed")

    # -- logs in the job's folder ------------------------------------------------
    def job_log(self, key: tuple[int, int] | None, line: str, *, job_id: str | None = None) -> None:
        """Append a line to the job's log (and, for a task's line, to the task's log)."""
        entry = self.jobs.get(key) if key is not None else None
        job_id = job_id or (entry[0] if entry else None)
        if not job_id:
            return
        try:
            d = self.datadir.job_dir(job_id)
            d.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
            prefix = f"task {entry[1]} attempt {key[1]}: " if entry and key else ""
            with open(d / "job.log", "a", encoding="utf-8") as f:
                f.write(f"{stamp} {prefix}{line}\n")
            if entry and key:
                (d / "logs").mkdir(exist_ok=True)
                with open(d / "logs" / f"task-{entry[1]:04d}.log", "a", encoding="utf-8") as f:
                    f.write(f"{stamp} attempt {key[1]}: {line}\n")
        except OSError:
            pass

    def _after(self, key: tuple[int, int]) -> None:
        """Write the job's manifest once it has ended."""
        entry = self.jobs.get(key)
        if entry is None:
            return
        job = self.store.get_job(entry[0])
        if job is not None and job["state"] in TERMINAL:
            write_manifest(self.datadir, self.store, entry[0])

    # -- reports ---------------------------------------------------------------
    def handle(self, msg: Any) -> None:
        """Apply one report of a worker (step 1 of the module docstring), shipped files first."""
        key = (msg.task_id, msg.attempt)
        entry = self.jobs.get(key)
        if msg.files and entry is not None and key not in self.canceling:
            try:
                write_shipped(self.datadir.job_dir(entry[0]), msg.files)
            except OSError as e:
                self.job_log(key, f"cannot store shipped files: {e}")
        if isinstance(msg, Heartbeat):
            if not self.store.heartbeat(*key, self.lease_s):
                self._stale(key)
        elif isinstance(msg, Progress):
            if not self.store.report_progress(msg, self.lease_s):
                self._stale(key)
        elif isinstance(msg, FrameDone):
            self.store.frame_done(msg)
        elif isinstance(msg, Log):
            if key not in self.canceling:
                self.job_log(key, msg.line)
        elif isinstance(msg, Done):
            if self.store.finish_task(msg):
                self.job_log(key, f"succeeded: {len(msg.result.outputs)} files")
                if entry is not None and entry[2] in FRAME_KINDS:  # its frames replace its pass preview
                    (self.datadir.job_dir(entry[0]) / "preview" / f"task-{entry[1]}.png").unlink(missing_ok=True)
                self._after(key)
        elif isinstance(msg, Failed):
            error = msg.error
            if msg.param:
                error = f"{field_name(msg.param, entry[2] if entry else None)}: {error}"
            if self.store.finish_task(msg.model_copy(update={"error": error})):
                self.job_log(key, f"failed: {error}")
                if msg.traceback:
                    self.job_log(key, msg.traceback.rstrip())
                self._after(key)
        elif isinstance(msg, Exit):
            code = msg.code
            if key in self.canceling:
                self.canceling.discard(key)
                if self.store.cancel_running(*key):
                    self.job_log(key, "canceled (worker stopped)")
            else:
                new = self.store.lose_attempt(*key, f"worker exited with code {code} before reporting")
                if new is not None:
                    self.job_log(key, f"worker lost (exit {code}); task {new}")
            self._after(key)
            self.jobs.pop(key, None)

    def _stale(self, key: tuple[int, int]) -> None:
        """A report from an attempt the store no longer runs: stop that worker."""
        if key in self.executor.active():
            self.executor.kill(*key)

    # -- housekeeping ----------------------------------------------------------
    def housekeeping(self) -> None:
        """Kill and requeue attempts whose lease expired, and stop the running attempts of canceled jobs."""
        for key in self.store.expired_leases():
            self.executor.kill(*key)
            self.canceling.discard(key)
            new = self.store.lose_attempt(*key, "lease expired (no heartbeat)")
            if new is not None:
                self.job_log(key, f"lease expired; task {new}")
                self._after(key)
        active = self.executor.active()
        for t in self.store.running_tasks():
            key = (t["id"], t["attempt"])
            if t["cancel_requested"]:
                if key in active:
                    if key not in self.canceling:
                        self.canceling.add(key)
                        self.executor.kill(*key)
                elif self.store.cancel_running(*key):
                    write_manifest(self.datadir, self.store, t["job_id"])

    def fill(self) -> None:
        """Start queued tasks while the executor has room; a task that cannot start fails with the reason."""
        while self.executor.capacity() > 0 and not self._stop.is_set():
            run = self.store.claim_next(self.owner, self.lease_s)
            if run is None:
                return
            key = (run.task_id, run.attempt)
            self.jobs[key] = (run.job_id, run.index, run.kind)
            try:
                run = self._prepare(run)
                worker = self.executor.start(run)
            except Exception as e:
                error = f"cannot start the task: {type(e).__name__}: {e}"
                self.store.finish_task(Failed(task_id=run.task_id, attempt=run.attempt, error=error))
                self.job_log(key, error)
                self._after(key)
                continue
            self.store.set_worker(*key, worker)
            skipped = f"; {len(run.spec.skip_frames)} frames already on disk" if run.spec.skip_frames else ""
            self.job_log(key, f"started on {worker}{skipped}")

    def _prepare(self, run: TaskRun) -> TaskRun:
        """Keep the config in the job folder, and tell a frame task which frames are on disk."""
        job_dir = self.datadir.job_dir(run.job_id)
        job_dir.mkdir(parents=True, exist_ok=True)
        kept = job_dir / "config.toml"
        if not kept.exists():
            tmp = job_dir / ".config.toml.tmp"
            tmp.write_text(run.spec.config, encoding="utf-8")
            os.replace(tmp, kept)
        on_disk = frames_on_disk(job_dir, run.spec)
        if on_disk:
            run = dataclasses.replace(run, spec=run.spec.model_copy(update={"skip_frames": tuple(on_disk)}))
        return run
