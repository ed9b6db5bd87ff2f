"""The durable job store: one SQLite database in WAL mode.

Tables
------
``jobs``    one row per submitted job (kind, config text, settings, state, priority,
            progress, result) with an optional unique ``idempotency_key``.
``tasks``   the units an executor runs: one per still or match, one per frame range of a
            fly-through.  Each carries an ``attempt`` counter and a lease
            (``lease_owner``, ``lease_expires``) renewed by the worker's heartbeats.
``events``  an append-only log per job (state changes, progress, previews) that the
            Server-Sent-Events endpoint streams from, resumable by event id.

State machine
-------------
task:  queued → running → succeeded | failed | canceled, and running → queued again when
       its lease is lost (worker killed, heartbeats stopped) while ``attempt < max_attempts``.
job:   derived from its tasks: canceled once a cancel was asked and no task runs; failed if
       any task failed; succeeded when all did; running when any task runs or finished;
       otherwise queued.

Every report from a worker names ``(task_id, attempt)``; it changes the row only while
the task is running *that* attempt, so reports from a stale attempt (one whose lease was
lost and whose task was handed to a new worker) are ignored.

Writes happen in short transactions; each thread has its own connection
(``check_same_thread`` stays on) and ``busy_timeout`` serialises writers.  WAL lets the
HTTP handlers read while the dispatcher writes.  On open, tasks left ``running`` by a
previous process are requeued (their attempt is kept, so the stale worker's reports, if
any, are ignored).
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

TERMINAL = ("succeeded", "failed", "canceled")
JOB_STATES = ("queued", "running") + TERMINAL

SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    kind TEXT NOT NULL,
    state TEXT NOT NULL,
    priority INTEGER NOT NULL DEFAULT 0,
    config TEXT NOT NULL,
    settings TEXT NOT NULL,
    idempotency_key TEXT UNIQUE,
    request_hash TEXT,
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    progress REAL NOT NULL DEFAULT 0,
    message TEXT NOT NULL DEFAULT '',
    error TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    preview TEXT,
    result TEXT
);
CREATE INDEX IF NOT EXISTS jobs_seq ON jobs(seq);
CREATE TABLE IF NOT EXISTS tasks (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id TEXT NOT NULL REFERENCES jobs(id),
    idx INTEGER NOT NULL,
    state TEXT NOT NULL,
    priority INTEGER NOT NULL DEFAULT 0,
    spec TEXT NOT NULL,
    attempt INTEGER NOT NULL DEFAULT 0,
    max_attempts INTEGER NOT NULL DEFAULT 3,
    lease_owner TEXT,
    lease_expires REAL,
    worker TEXT,
    progress REAL NOT NULL DEFAULT 0,
    message TEXT NOT NULL DEFAULT '',
    preview TEXT,
    result TEXT,
    error TEXT,
    started REAL,
    finished REAL
);
CREATE INDEX IF NOT EXISTS tasks_queue ON tasks(state, priority DESC, id);
CREATE INDEX IF NOT EXISTS tasks_job ON tasks(job_id, idx);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id TEXT NOT NULL,
    type TEXT NOT NULL,
    data TEXT NOT NULL,
    ts REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS events_job ON events(job_id, id);
"""


@dataclass(frozen=True)
class TaskRun:
    """What an executor needs to run one attempt of a task."""

    task_id: int
    attempt: int
    job_id: str
    kind: str
    index: int
    spec: dict
    lease_owner: str


class IdempotencyConflict(Exception):
    """The Idempotency-Key was used before with a different request."""


class Store:
    """Thread-safe access to the SQLite job store."""

    def __init__(self, path: str | Path, *, max_attempts: int = 3):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.max_attempts = max_attempts
        self._local = threading.local()
        self._write_lock = threading.Lock()
        self._conns: list[sqlite3.Connection] = []
        self._conns_lock = threading.Lock()
        with self._write_lock:
            self._conn().executescript(SCHEMA)
        self.requeued_on_open = self.requeue_running("service restarted")

    # -- connections -------------------------------------------------------------
    def _conn(self) -> sqlite3.Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            c.row_factory = sqlite3.Row
            c.execute("PRAGMA journal_mode=WAL")
            c.execute("PRAGMA synchronous=NORMAL")
            c.execute("PRAGMA busy_timeout=30000")
            c.execute("PRAGMA foreign_keys=ON")
            self._local.conn = c
            with self._conns_lock:
                self._conns.append(c)
        return c

    class _Tx:
        def __init__(self, store: Store):
            self.store = store

        def __enter__(self) -> sqlite3.Connection:
            self.store._write_lock.acquire()
            self.db = self.store._conn()
            self.db.execute("BEGIN IMMEDIATE")
            return self.db

        def __exit__(self, et, ev, tb):
            try:
                self.db.execute("COMMIT" if et is None else "ROLLBACK")
            finally:
                self.store._write_lock.release()
            return False

    def _tx(self) -> Store._Tx:
        return Store._Tx(self)

    def close(self) -> None:
        with self._conns_lock:
            for c in self._conns:
                try:
                    c.close()
                except sqlite3.ProgrammingError:
                    pass  # opened by another thread; it goes with that thread
            self._conns.clear()
        self._local = threading.local()

    # -- events ----------------------------------------------------------------
    @staticmethod
    def _event(db: sqlite3.Connection, job_id: str, type_: str, data: dict) -> None:
        db.execute(
            "INSERT INTO events(job_id, type, data, ts) VALUES (?,?,?,?)",
            (job_id, type_, json.dumps(data, separators=(",", ":")), time.time()),
        )

    def events_after(self, job_id: str, after: int, limit: int = 500) -> list[dict]:
        rows = (
            self._conn()
            .execute(
                "SELECT id, type, data, ts FROM events WHERE job_id=? AND id>? ORDER BY id LIMIT ?",
                (job_id, after, limit),
            )
            .fetchall()
        )
        return [{"id": r["id"], "type": r["type"], "data": json.loads(r["data"]), "ts": r["ts"]} for r in rows]

    def last_event_id(self, job_id: str) -> int:
        return int(
            self._conn().execute("SELECT COALESCE(MAX(id), 0) FROM events WHERE job_id=?", (job_id,)).fetchone()[0]
        )

    # -- jobs ------------------------------------------------------------------
    def find_idempotent(self, key: str) -> dict | None:
        """``{"id", "request_hash"}`` of the job submitted with this Idempotency-Key, if any."""
        r = self._conn().execute("SELECT id, request_hash FROM jobs WHERE idempotency_key=?", (key,)).fetchone()
        return dict(r) if r is not None else None

    def create_job(
        self,
        *,
        kind: str,
        config: str,
        settings: dict,
        priority: int,
        task_specs: list[dict],
        idempotency_key: str | None = None,
        request_hash: str | None = None,
        job_id: str | None = None,
    ) -> tuple[dict, bool]:
        """Insert a job and its tasks in one transaction.  Returns ``(job, created)``.

        With an ``idempotency_key`` already used by the same request, the existing job is
        returned with ``created=False``; used by a different request, raises
        :class:`IdempotencyConflict`.
        """
        now = time.time()
        job_id = job_id or uuid.uuid4().hex
        with self._tx() as db:
            if idempotency_key is not None:
                row = db.execute(
                    "SELECT id, request_hash FROM jobs WHERE idempotency_key=?", (idempotency_key,)
                ).fetchone()
                if row is not None:
                    if row["request_hash"] != request_hash:
                        raise IdempotencyConflict(idempotency_key)
                    existing = row["id"]
                    return self._job_row(db, existing), False
            seq = db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs").fetchone()[0]
            db.execute(
                "INSERT INTO jobs(id, seq, kind, state, priority, config, settings, idempotency_key,"
                " request_hash, created, message) VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                (
                    job_id,
                    seq,
                    kind,
                    "queued",
                    priority,
                    config,
                    json.dumps(settings),
                    idempotency_key,
                    request_hash,
                    now,
                    "queued",
                ),
            )
            db.executemany(
                "INSERT INTO tasks(job_id, idx, state, priority, spec, max_attempts) VALUES (?,?,?,?,?,?)",
                [(job_id, i, "queued", priority, json.dumps(s), self.max_attempts) for i, s in enumerate(task_specs)],
            )
            self._event(db, job_id, "state", {"state": "queued", "progress": 0.0})
            return self._job_row(db, job_id), True

    def _job_row(self, db: sqlite3.Connection, job_id: str) -> dict | None:
        r = db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        return _job_dict(r) if r is not None else None

    def get_job(self, job_id: str, *, with_tasks: bool = False) -> dict | None:
        db = self._conn()
        job = self._job_row(db, job_id)
        if job is not None and with_tasks:
            job["tasks"] = [
                _task_dict(t) for t in db.execute("SELECT * FROM tasks WHERE job_id=? ORDER BY idx", (job_id,))
            ]
        return job

    def list_jobs(self, *, state: str | None = None, limit: int = 100, before_seq: int | None = None) -> list[dict]:
        q = "SELECT * FROM jobs"
        cond, args = [], []
        if state:
            cond.append("state=?")
            args.append(state)
        if before_seq is not None:
            cond.append("seq<?")
            args.append(before_seq)
        if cond:
            q += " WHERE " + " AND ".join(cond)
        q += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        return [_job_dict(r) for r in self._conn().execute(q, args)]

    def counts(self) -> dict[str, int]:
        out = {s: 0 for s in JOB_STATES}
        for r in self._conn().execute("SELECT state, COUNT(*) AS n FROM jobs GROUP BY state"):
            out[r["state"]] = r["n"]
        return out

    def request_cancel(self, job_id: str) -> dict | None:
        """Mark a job for cancellation; queued tasks are canceled at once.

        Returns the job, or None if unknown.  Running tasks are stopped by the dispatcher,
        which sees ``cancel_requested`` on its next tick.
        """
        with self._tx() as db:
            job = self._job_row(db, job_id)
            if job is None:
                return None
            if job["state"] in TERMINAL:
                return job
            db.execute("UPDATE jobs SET cancel_requested=1 WHERE id=?", (job_id,))
            db.execute(
                "UPDATE tasks SET state='canceled', finished=? WHERE job_id=? AND state='queued'", (time.time(), job_id)
            )
            self._event(db, job_id, "cancel", {"message": "cancel requested"})
            self._refresh_job(db, job_id)
            return self._job_row(db, job_id)

    def retry_job(self, job_id: str) -> dict | None:
        """Requeue the failed or canceled tasks of a finished job (fresh attempt budget)."""
        with self._tx() as db:
            job = self._job_row(db, job_id)
            if job is None or job["state"] not in ("failed", "canceled"):
                return job
            db.execute(
                "UPDATE tasks SET state='queued', attempt=0, error=NULL, progress=0, message='requeued',"
                " lease_owner=NULL, lease_expires=NULL, finished=NULL"
                " WHERE job_id=? AND state IN ('failed','canceled')",
                (job_id,),
            )
            db.execute("UPDATE jobs SET cancel_requested=0, error=NULL, finished=NULL WHERE id=?", (job_id,))
            self._event(db, job_id, "retry", {"message": "retry requested"})
            self._refresh_job(db, job_id)
            return self._job_row(db, job_id)

    # -- dispatcher side -------------------------------------------------------
    def claim_next(self, owner: str, lease_s: float, *, worker: str | None = None) -> TaskRun | None:
        """Move the highest-priority, oldest queued task to running with a new attempt and lease."""
        now = time.time()
        with self._tx() as db:
            r = db.execute(
                "SELECT t.id, t.job_id, t.idx, t.spec, t.attempt, j.kind FROM tasks t"
                " JOIN jobs j ON j.id = t.job_id"
                " WHERE t.state='queued' AND j.cancel_requested=0"
                " ORDER BY t.priority DESC, t.id LIMIT 1"
            ).fetchone()
            if r is None:
                return None
            attempt = r["attempt"] + 1
            db.execute(
                "UPDATE tasks SET state='running', attempt=?, lease_owner=?, lease_expires=?, worker=?,"
                " started=COALESCE(started, ?), message=? WHERE id=?",
                (attempt, owner, now + lease_s, worker, now, f"starting (attempt {attempt})", r["id"]),
            )
            self._event(db, r["job_id"], "task", {"task": r["idx"], "state": "running", "attempt": attempt})
            self._refresh_job(db, r["job_id"])
            return TaskRun(
                task_id=r["id"],
                attempt=attempt,
                job_id=r["job_id"],
                kind=r["kind"],
                index=r["idx"],
                spec=json.loads(r["spec"]),
                lease_owner=owner,
            )

    def set_worker(self, task_id: int, attempt: int, worker: str) -> None:
        with self._tx() as db:
            db.execute(
                "UPDATE tasks SET worker=? WHERE id=? AND attempt=? AND state='running'", (worker, task_id, attempt)
            )

    def heartbeat(self, task_id: int, attempt: int, lease_s: float) -> bool:
        """Renew the lease of a running attempt; False when the attempt is stale."""
        with self._tx() as db:
            n = db.execute(
                "UPDATE tasks SET lease_expires=? WHERE id=? AND attempt=? AND state='running'",
                (time.time() + lease_s, task_id, attempt),
            ).rowcount
        return n == 1

    def report_progress(
        self,
        task_id: int,
        attempt: int,
        fraction: float,
        message: str,
        preview: str | None = None,
        lease_s: float | None = None,
    ) -> bool:
        """Record progress of a running attempt (also renews its lease); False when stale."""
        fraction = min(1.0, max(0.0, float(fraction)))
        with self._tx() as db:
            row = db.execute(
                "SELECT job_id, idx FROM tasks WHERE id=? AND attempt=? AND state='running'", (task_id, attempt)
            ).fetchone()
            if row is None:
                return False
            sets = "progress=?, message=?"
            args: list[Any] = [fraction, message[:500]]
            if preview:
                sets += ", preview=?"
                args.append(preview)
            if lease_s is not None:
                sets += ", lease_expires=?"
                args.append(time.time() + lease_s)
            db.execute(f"UPDATE tasks SET {sets} WHERE id=?", args + [task_id])
            job_id = row["job_id"]
            if preview:
                db.execute("UPDATE jobs SET preview=? WHERE id=?", (preview, job_id))
            prog = self._job_progress(db, job_id)
            db.execute("UPDATE jobs SET progress=?, message=? WHERE id=?", (prog, message[:500], job_id))
            data = {"task": row["idx"], "progress": prog, "task_progress": fraction, "message": message[:500]}
            if preview:
                data["preview"] = preview
            self._event(db, job_id, "progress", data)
            return True

    def finish_task(
        self, task_id: int, attempt: int, state: str, *, result: dict | None = None, error: str | None = None
    ) -> bool:
        """Finish a running attempt as succeeded/failed; False (and no change) when stale."""
        assert state in ("succeeded", "failed")
        with self._tx() as db:
            row = db.execute(
                "SELECT job_id, idx FROM tasks WHERE id=? AND attempt=? AND state='running'", (task_id, attempt)
            ).fetchone()
            if row is None:
                return False
            preview = (result or {}).get("preview")
            if preview:
                db.execute("UPDATE tasks SET preview=? WHERE id=?", (preview, task_id))
                db.execute("UPDATE jobs SET preview=? WHERE id=?", (preview, row["job_id"]))
            db.execute(
                "UPDATE tasks SET state=?, result=?, error=?, finished=?, lease_owner=NULL,"
                " lease_expires=NULL, progress=CASE WHEN ?='succeeded' THEN 1.0 ELSE progress END,"
                " message=? WHERE id=?",
                (
                    state,
                    json.dumps(result) if result is not None else None,
                    error,
                    time.time(),
                    state,
                    state if error is None else error[:500],
                    task_id,
                ),
            )
            self._event(
                db,
                row["job_id"],
                "task",
                {"task": row["idx"], "state": state, "attempt": attempt, **({"error": error} if error else {})},
            )
            if state == "failed":
                # One failed task fails the job: its queued siblings are canceled.
                db.execute(
                    "UPDATE tasks SET state='canceled', finished=? WHERE job_id=? AND state='queued'",
                    (time.time(), row["job_id"]),
                )
                db.execute("UPDATE jobs SET error=COALESCE(error, ?) WHERE id=?", (error, row["job_id"]))
            self._refresh_job(db, row["job_id"])
            return True

    def lose_attempt(self, task_id: int, attempt: int, reason: str) -> str | None:
        """The worker of a running attempt is gone: requeue (within the retry limit) or fail.

        Returns the new task state, or None if the attempt was stale.
        """
        with self._tx() as db:
            row = db.execute(
                "SELECT job_id, idx, max_attempts FROM tasks WHERE id=? AND attempt=? AND state='running'",
                (task_id, attempt),
            ).fetchone()
            if row is None:
                return None
            job_id = row["job_id"]
            cancel = db.execute("SELECT cancel_requested FROM jobs WHERE id=?", (job_id,)).fetchone()[0]
            if cancel:
                new = "canceled"
                db.execute(
                    "UPDATE tasks SET state='canceled', finished=?, lease_owner=NULL, lease_expires=NULL,"
                    " message='canceled' WHERE id=?",
                    (time.time(), task_id),
                )
            elif attempt < row["max_attempts"]:
                new = "queued"
                db.execute(
                    "UPDATE tasks SET state='queued', lease_owner=NULL, lease_expires=NULL, progress=0,"
                    " message=? WHERE id=?",
                    (f"requeued: {reason}", task_id),
                )
            else:
                new = "failed"
                err = f"task {row['idx']}: {reason} on all {attempt} attempts"
                db.execute(
                    "UPDATE tasks SET state='failed', finished=?, error=?, lease_owner=NULL,"
                    " lease_expires=NULL, message=? WHERE id=?",
                    (time.time(), err, err, task_id),
                )
                db.execute(
                    "UPDATE tasks SET state='canceled', finished=? WHERE job_id=? AND state='queued'",
                    (time.time(), job_id),
                )
                db.execute("UPDATE jobs SET error=COALESCE(error, ?) WHERE id=?", (err, job_id))
            self._event(db, job_id, "task", {"task": row["idx"], "state": new, "attempt": attempt, "message": reason})
            self._refresh_job(db, job_id)
            return new

    def cancel_running(self, task_id: int, attempt: int) -> bool:
        """A running attempt of a canceled job was stopped."""
        with self._tx() as db:
            row = db.execute(
                "SELECT job_id, idx FROM tasks WHERE id=? AND attempt=? AND state='running'", (task_id, attempt)
            ).fetchone()
            if row is None:
                return False
            db.execute(
                "UPDATE tasks SET state='canceled', finished=?, lease_owner=NULL, lease_expires=NULL,"
                " message='canceled' WHERE id=?",
                (time.time(), task_id),
            )
            self._event(db, row["job_id"], "task", {"task": row["idx"], "state": "canceled", "attempt": attempt})
            self._refresh_job(db, row["job_id"])
            return True

    def running_tasks(self) -> list[dict]:
        return [
            _task_dict(r)
            for r in self._conn().execute(
                "SELECT t.*, j.cancel_requested FROM tasks t JOIN jobs j ON j.id=t.job_id WHERE t.state='running'"
            )
        ]

    def expired_leases(self, now: float | None = None) -> list[tuple[int, int]]:
        now = time.time() if now is None else now
        return [
            (r["id"], r["attempt"])
            for r in self._conn().execute(
                "SELECT id, attempt FROM tasks WHERE state='running' AND lease_expires < ?", (now,)
            )
        ]

    def requeue_running(self, reason: str) -> int:
        """Requeue every running task (used at start-up: their workers died with the old process)."""
        with self._tx() as db:
            rows = db.execute(
                "SELECT t.id, t.job_id, t.idx, j.cancel_requested FROM tasks t"
                " JOIN jobs j ON j.id=t.job_id WHERE t.state='running'"
            ).fetchall()
            for r in rows:
                new = "canceled" if r["cancel_requested"] else "queued"
                db.execute(
                    "UPDATE tasks SET state=?, lease_owner=NULL, lease_expires=NULL, progress=0, message=? WHERE id=?",
                    (new, f"requeued: {reason}" if new == "queued" else "canceled", r["id"]),
                )
                self._event(db, r["job_id"], "task", {"task": r["idx"], "state": new, "message": reason})
            for job_id in {r["job_id"] for r in rows}:
                self._refresh_job(db, job_id)
            return len(rows)

    # -- derived job state -----------------------------------------------------
    @staticmethod
    def _job_progress(db: sqlite3.Connection, job_id: str) -> float:
        r = db.execute(
            "SELECT AVG(CASE WHEN state='succeeded' THEN 1.0 ELSE progress END) FROM tasks WHERE job_id=?", (job_id,)
        ).fetchone()
        return float(r[0] or 0.0)

    def _refresh_job(self, db: sqlite3.Connection, job_id: str) -> None:
        job = db.execute("SELECT state, cancel_requested, started FROM jobs WHERE id=?", (job_id,)).fetchone()
        counts = {
            r["state"]: r["n"]
            for r in db.execute("SELECT state, COUNT(*) AS n FROM tasks WHERE job_id=? GROUP BY state", (job_id,))
        }
        total = sum(counts.values())
        running = counts.get("running", 0)
        if job["cancel_requested"] and not running and not counts.get("queued", 0):
            new = "canceled"
        elif counts.get("failed", 0) and not running:
            new = "failed"
        elif counts.get("succeeded", 0) == total:
            new = "succeeded"
        elif running or counts.get("succeeded", 0) or counts.get("failed", 0):
            new = "running"
        else:
            new = "queued"
        now = time.time()
        prog = self._job_progress(db, job_id)
        if new == job["state"]:
            db.execute("UPDATE jobs SET progress=? WHERE id=?", (prog, job_id))
            return
        sets, args = ["state=?", "progress=?", "message=?"], [new, prog, new]
        if new == "running" and job["started"] is None:
            sets.append("started=?")
            args.append(now)
        if new in TERMINAL:
            sets.append("finished=?")
            args.append(now)
            if new == "succeeded":
                results = [
                    json.loads(r["result"]) if r["result"] else {}
                    for r in db.execute("SELECT result FROM tasks WHERE job_id=? ORDER BY idx", (job_id,))
                ]
                sets.append("result=?")
                args.append(json.dumps(merge_results(results)))
        else:
            sets.append("finished=NULL")
        db.execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id=?", args + [job_id])
        self._event(db, job_id, "state", {"state": new, "progress": prog})


def merge_results(results: Iterable[dict]) -> dict:
    """Concatenate the per-task outputs and keep per-task statistics in task order."""
    outputs: list[str] = []
    stats: list[dict] = []
    for r in results:
        outputs.extend(r.get("outputs", []))
        if r.get("stats") is not None:
            stats.append(r["stats"])
    return {"outputs": outputs, "stats": stats}


def _job_dict(r: sqlite3.Row) -> dict:
    d = dict(r)
    d["settings"] = json.loads(d["settings"])
    d["result"] = json.loads(d["result"]) if d["result"] else None
    d["cancel_requested"] = bool(d["cancel_requested"])
    return d


def _task_dict(r: sqlite3.Row) -> dict:
    d = dict(r)
    d["spec"] = json.loads(d["spec"])
    d["result"] = json.loads(d["result"]) if d["result"] else None
    return d
