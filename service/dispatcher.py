"""The dispatcher: one thread that moves work between the store and an executor.

Each tick (``tick_s``, 50 ms by default) it

1. applies the executor's reports — heartbeats renew leases, progress and previews
   are recorded, ``done``/``error`` finish the attempt, and an ``exit`` without either
   means the worker was lost (requeue within the retry limit).  Every report names its
   attempt; the store ignores stale ones, and the dispatcher kills a worker whose
   attempt turns out stale (it lost its lease and the task moved on);
2. every ``housekeeping_s``: kills and requeues attempts whose lease expired (no
   heartbeat for ``lease_s``), and stops the running attempts of canceled jobs;
3. starts queued tasks (highest priority first, then oldest) while the executor has room.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid

from .assets import DataDir
from .executors import Executor
from .store import Store

log = logging.getLogger("forest.service")


class Dispatcher:
    def __init__(
        self,
        store: Store,
        executor: Executor,
        datadir: DataDir,
        *,
        lease_s: float = 15.0,
        tick_s: float = 0.05,
        housekeeping_s: float = 0.25,
    ):
        self.store = store
        self.executor = executor
        self.datadir = datadir
        self.lease_s = lease_s
        self.tick_s = tick_s
        self.housekeeping_s = housekeeping_s
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self.jobs: dict[tuple[int, int], str] = {}  # (task, attempt) → job id
        self.canceling: set[tuple[int, int]] = set()
        self.paused = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.errors = 0

    # -- lifecycle -------------------------------------------------------------
    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="dispatcher", daemon=True)
            self._thread.start()

    def stop(self) -> None:
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
                if not self.paused:
                    self.fill()
            except Exception:
                self.errors += 1
                log.exception("dispatcher tick failed")
                time.sleep(0.2)

    # -- logging into the job's folder ------------------------------------------
    def job_log(self, job_id: str | None, line: str) -> None:
        if not job_id:
            return
        try:
            d = self.datadir.job_dir(job_id)
            d.mkdir(parents=True, exist_ok=True)
            stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
            with open(d / "job.log", "a", encoding="utf-8") as f:
                f.write(f"{stamp} {line}\n")
        except OSError:
            pass

    # -- reports ---------------------------------------------------------------
    def handle(self, msg: dict) -> None:
        key = (int(msg.get("task_id", -1)), int(msg.get("attempt", -1)))
        typ = msg.get("type")
        job_id = self.jobs.get(key)
        if typ == "heartbeat":
            if not self.store.heartbeat(*key, self.lease_s):
                self._stale(key)
        elif typ == "progress":
            ok = self.store.report_progress(
                *key, msg.get("fraction", 0.0), str(msg.get("message", "")), msg.get("preview"), self.lease_s
            )
            if not ok:
                self._stale(key)
        elif typ == "log":
            # local workers write their own lines into the job log; remote ones report them
            if job_id and key not in self.canceling and self.executor.name != "local":
                self.job_log(job_id, f"task {key[0]} attempt {key[1]}: {msg.get('line', '')}")
        elif typ == "done":
            if self.store.finish_task(*key, "succeeded", result=msg.get("result") or {}):
                self.job_log(job_id, f"task {key[0]} attempt {key[1]}: succeeded")
        elif typ == "error":
            err = str(msg.get("error", "failed"))
            if self.store.finish_task(*key, "failed", error=err):
                self.job_log(job_id, f"task {key[0]} attempt {key[1]}: failed: {err}")
        elif typ == "exit":
            code = msg.get("code")
            if key in self.canceling:
                self.canceling.discard(key)
                if self.store.cancel_running(*key):
                    self.job_log(job_id, f"task {key[0]} attempt {key[1]}: canceled (worker stopped)")
            else:
                new = self.store.lose_attempt(*key, f"worker exited with code {code} before reporting")
                if new is not None:
                    self.job_log(job_id, f"task {key[0]} attempt {key[1]}: worker lost (exit {code}); task {new}")
            self.jobs.pop(key, None)

    def _stale(self, key: tuple[int, int]) -> None:
        """A report from an attempt the store no longer runs: stop that worker."""
        if key in self.executor.active():
            self.executor.kill(*key)

    # -- housekeeping ----------------------------------------------------------
    def housekeeping(self) -> None:
        for key in self.store.expired_leases():
            self.executor.kill(*key)
            self.canceling.discard(key)
            new = self.store.lose_attempt(*key, "lease expired (no heartbeat)")
            if new is not None:
                self.job_log(self.jobs.get(key), f"task {key[0]} attempt {key[1]}: lease expired; task {new}")
        active = self.executor.active()
        for t in self.store.running_tasks():
            key = (t["id"], t["attempt"])
            if t["cancel_requested"]:
                if key in active:
                    if key not in self.canceling:
                        self.canceling.add(key)
                        self.executor.kill(*key)
                else:
                    self.store.cancel_running(*key)

    def fill(self) -> None:
        while self.executor.capacity() > 0 and not self._stop.is_set():
            run = self.store.claim_next(self.owner, self.lease_s)
            if run is None:
                return
            key = (run.task_id, run.attempt)
            self.jobs[key] = run.job_id
            try:
                worker = self.executor.start(run)
            except Exception as e:
                self.store.finish_task(*key, "failed", error=f"cannot start worker: {type(e).__name__}: {e}")
                self.job_log(run.job_id, f"task {run.task_id} attempt {run.attempt}: cannot start: {e}")
                continue
            self.store.set_worker(*key, worker)
            self.job_log(run.job_id, f"task {run.task_id} (#{run.index}) attempt {run.attempt}: started on {worker}")
