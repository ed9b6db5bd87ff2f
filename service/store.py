"""The durable job store: one SQLite database in WAL mode.

Tables
------
``jobs``    one row per submitted job (kind, name, config text, settings, state, priority,
            progress, result, trees) with an optional unique ``idempotency_key``.
``tasks``   the units an executor runs: one per frame of a fly-through (or per chunk of
            ``frames_per_task`` frames), one per still, match or export.  Each keeps its
            :class:`~forest.service.models.TaskSpec` (without the config text, which the job
            keeps once and a claim puts back), an ``attempt`` counter, a lease
            (``lease_owner``, ``lease_expires``) renewed by the worker's heartbeats, and
            what the page shows: current frame, passes done, ETA, time, error.
``frames``  one row per frame on disk: the task and attempt that rendered it, its time,
            its thumbnail, and whether it was ``resumed`` (found on disk, not re-rendered).
``events``  an append-only log per job (state changes, progress, frames) that the
            Server-Sent-Events endpoint streams from, resumable by event id.

State machine
-------------
task:  queued → running → succeeded | failed | canceled, and running → queued again when
       its lease is lost (worker killed, heartbeats stopped) while ``attempt < max_attempts``;
       a finished task can be requeued on its own (``requeue_task``), a finished job resumed
       (``resume_job``: its failed and canceled tasks run again, frames on disk are skipped).
job:   derived from its tasks: once none is queued or running, failed if any failed, else
       canceled if any was canceled, else succeeded; before that running when any task runs
       or finished, otherwise queued.

Every report from a worker names ``(task_id, attempt)``; it changes the row only while
the task is running *that* attempt, so reports from a stale attempt (one whose lease was
lost and whose task was handed to a new worker) are ignored.

Writes happen in short transactions; each thread has its own connection and one lock
serialises writers.  WAL lets the HTTP handlers read while the dispatcher writes.  After
each transaction that appended events the store calls its ``on_events`` listener with
the jobs concerned (the SSE streams wait on it).  On open, tasks left ``running`` by a
previous process are requeued (their attempt is kept, so the stale worker's reports,
if any, are ignored), and a store written by the first version is migrated in place.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .models import Done, Failed, FrameDone, Progress, TaskResult, TaskSpec

TERMINAL = ("succeeded", "failed", "canceled")
JOB_STATES = ("queued", "running") + TERMINAL
SCHEMA_VERSION = 2

SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    seq INTEGER NOT NULL,
    kind TEXT NOT NULL,
    name TEXT,
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
    result TEXT,
    trees INTEGER,
    frames_total INTEGER NOT NULL DEFAULT 0,
    frames_done INTEGER NOT NULL DEFAULT 0,
    outputs_deleted INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS jobs_seq ON jobs(seq);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state, finished);
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
    finished REAL,
    frame INTEGER,
    passes_done INTEGER,
    passes_total INTEGER,
    eta_s REAL,
    seconds REAL,
    frame_list TEXT
);
CREATE INDEX IF NOT EXISTS tasks_queue ON tasks(state, priority DESC, id);
CREATE INDEX IF NOT EXISTS tasks_job ON tasks(job_id, idx);
CREATE TABLE IF NOT EXISTS frames (
    job_id TEXT NOT NULL,
    frame INTEGER NOT NULL,
    task_idx INTEGER NOT NULL,
    attempt INTEGER NOT NULL,
    seconds REAL NOT NULL DEFAULT 0,
    finished REAL NOT NULL,
    resumed INTEGER NOT NULL DEFAULT 0,
    thumb TEXT,
    outputs TEXT NOT NULL DEFAULT '[]',
    PRIMARY KEY (job_id, frame)
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id TEXT NOT NULL,
    type TEXT NOT NULL,
    data TEXT NOT NULL,
    ts REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS events_job ON events(job_id, id);
"""

#: Columns added since the first version of the schema (``ALTER TABLE … ADD COLUMN`` on open).
ADDED_COLUMNS = {
    "jobs": (
        ("name", "TEXT"),
        ("trees", "INTEGER"),
        ("frames_total", "INTEGER NOT NULL DEFAULT 0"),
        ("frames_done", "INTEGER NOT NULL DEFAULT 0"),
        ("outputs_deleted", "INTEGER NOT NULL DEFAULT 0"),
    ),
    "tasks": (
        ("frame", "INTEGER"),
        ("passes_done", "INTEGER"),
        ("passes_total", "INTEGER"),
        ("eta_s", "REAL"),
        ("seconds", "REAL"),
        ("frame_list", "TEXT"),
    ),
}


#: What a task's view shows (its frames from the column, or from the spec of a first-version row).
TASK_VIEW_COLUMNS = (
    "id, idx, state, attempt, max_attempts, progress, message, preview, error, worker, started, finished,"
    " frame, passes_done, passes_total, eta_s, seconds, COALESCE(frame_list, json_extract(spec, '$.frames')) AS frames"
)


@dataclass(frozen=True)
class TaskRun:
    """What an executor needs to run one attempt of a task."""

    task_id: int
    attempt: int
    job_id: str
    kind: str
    index: int
    spec: TaskSpec
    lease_owner: str


class IdempotencyConflict(Exception):
    """The Idempotency-Key was used before with a different request."""


class Store:
    """Thread-safe access to the SQLite job store."""

    def __init__(
        self,
        path: str | Path,
        *,
        max_attempts: int = 3,
        on_events: Callable[[set[str]], None] | None = None,
    ):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.max_attempts = max_attempts
        self.on_events = on_events
        self._local = threading.local()
        self._write_lock = threading.Lock()
        self._conns: list[sqlite3.Connection] = []
        self._conns_lock = threading.Lock()
        with self._write_lock:
            db = self._conn()
            self._migrate(db)
            db.executescript(SCHEMA)
            db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        self.requeued_on_open = self.requeue_running("service restarted")

    # -- connections -------------------------------------------------------------
    def _conn(self) -> sqlite3.Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
            c.row_factory = sqlite3.Row
            c.execute("PRAGMA journal_mode=WAL")
            c.execute("PRAGMA synchronous=NORMAL")
            c.execute("PRAGMA busy_timeout=30000")
            self._local.conn = c
            with self._conns_lock:
                self._conns.append(c)
        return c

    @staticmethod
    def _migrate(db: sqlite3.Connection) -> None:
        """Add the columns a store of the first version lacks (its tables exist, without them)."""
        for table, columns in ADDED_COLUMNS.items():
            have = {r[1] for r in db.execute(f"PRAGMA table_info({table})")}
            if not have:
                continue  # a new store: the schema creates the table whole
            for name, decl in columns:
                if name not in have:
                    db.execute(f"ALTER TABLE {table} ADD COLUMN {name} {decl}")
        have = {r[1] for r in db.execute("PRAGMA table_info(jobs)")}
        if have:  # names of first-version jobs lived in their settings
            db.execute(
                "UPDATE jobs SET name=json_extract(settings, '$.name') WHERE name IS NULL"
                " AND json_valid(settings) AND json_extract(settings, '$.name') IS NOT NULL"
            )

    class _Tx:
        def __init__(self, store: Store):
            self.store = store
            self.touched: set[str] = set()

        def __enter__(self) -> Store._Tx:
            self.store._write_lock.acquire()
            self.db = self.store._conn()
            self.db.execute("BEGIN IMMEDIATE")
            return self

        def execute(self, sql: str, args: Iterable[Any] = ()) -> sqlite3.Cursor:
            return self.db.execute(sql, tuple(args))

        def executemany(self, sql: str, rows: Iterable[Sequence[Any]]) -> sqlite3.Cursor:
            return self.db.executemany(sql, rows)

        def event(self, job_id: str, type_: str, data: dict) -> None:
            self.db.execute(
                "INSERT INTO events(job_id, type, data, ts) VALUES (?,?,?,?)",
                (job_id, type_, json.dumps(data, separators=(",", ":")), time.time()),
            )
            self.touched.add(job_id)

        def __exit__(self, et: type[BaseException] | None, ev: object, tb: object) -> None:
            try:
                self.db.execute("COMMIT" if et is None else "ROLLBACK")
            finally:
                self.store._write_lock.release()
            if et is None and self.touched and self.store.on_events is not None:
                self.store.on_events(self.touched)

    def _tx(self) -> Store._Tx:
        return Store._Tx(self)

    def close(self) -> None:
        """Close every thread's connection; a later call opens a new one."""
        with self._conns_lock:
            for c in self._conns:
                try:
                    c.close()
                except sqlite3.ProgrammingError:
                    pass
            self._conns.clear()
        self._local = threading.local()

    # -- events ----------------------------------------------------------------
    def events_after(self, job_id: str, after: int, limit: int = 500) -> list[dict]:
        """Up to ``limit`` events of ``job_id`` with id > ``after``, in order: ``{"id", "type", "data", "ts"}``."""
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
        """The newest event id of ``job_id`` (0 without events)."""
        return int(
            self._conn().execute("SELECT COALESCE(MAX(id), 0) FROM events WHERE job_id=?", (job_id,)).fetchone()[0]
        )

    def event_count(self) -> int:
        """Number of events stored, over all jobs."""
        return int(self._conn().execute("SELECT COUNT(*) FROM events").fetchone()[0])

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
        task_specs: list[TaskSpec],
        name: str | None = None,
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
        frames_total = sum(len(s.frames or ()) for s in task_specs)
        with self._tx() as tx:
            if idempotency_key is not None:
                row = tx.execute(
                    "SELECT id, request_hash FROM jobs WHERE idempotency_key=?", (idempotency_key,)
                ).fetchone()
                if row is not None:
                    if row["request_hash"] != request_hash:
                        raise IdempotencyConflict(idempotency_key)
                    return self._job_row(tx.db, row["id"]), False  # type: ignore[return-value]
            seq = tx.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs").fetchone()[0]
            tx.execute(
                "INSERT INTO jobs(id, seq, kind, name, state, priority, config, settings, idempotency_key,"
                " request_hash, created, message, frames_total) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (
                    job_id,
                    seq,
                    kind,
                    name,
                    "queued",
                    priority,
                    config,
                    json.dumps(settings),
                    idempotency_key,
                    request_hash,
                    now,
                    "queued",
                    frames_total,
                ),
            )
            tx.executemany(
                "INSERT INTO tasks(job_id, idx, state, priority, spec, max_attempts, frame_list)"
                " VALUES (?,?,?,?,?,?,?)",
                [
                    (
                        job_id,
                        s.index,
                        "queued",
                        priority,
                        s.model_dump_json(exclude={"config"}),
                        self.max_attempts,
                        json.dumps(list(s.frames)) if s.frames is not None else None,
                    )
                    for s in task_specs
                ],
            )
            tx.event(job_id, "state", {"state": "queued", "progress": 0.0})
            return self._job_row(tx.db, job_id), True  # type: ignore[return-value]

    def _job_row(self, db: sqlite3.Connection, job_id: str) -> dict | None:
        r = db.execute("SELECT * FROM jobs WHERE id=?", (job_id,)).fetchone()
        return _job_dict(r) if r is not None else None

    def get_job(self, job_id: str, *, with_tasks: bool = False) -> dict | None:
        """A job; ``with_tasks``: and its tasks as views need them (no spec, no result)."""
        db = self._conn()
        job = self._job_row(db, job_id)
        if job is not None and with_tasks:
            job["tasks"] = [
                {**dict(t), "frames": json.loads(t["frames"]) if t["frames"] else None}
                for t in db.execute(f"SELECT {TASK_VIEW_COLUMNS} FROM tasks WHERE job_id=? ORDER BY idx", (job_id,))
            ]
        return job

    def get_task(self, job_id: str, index: int) -> dict | None:
        """Task ``index`` of ``job_id`` as a dict (spec kept as JSON text), or None."""
        r = self._conn().execute("SELECT * FROM tasks WHERE job_id=? AND idx=?", (job_id, index)).fetchone()
        return _task_dict(r) if r is not None else None

    def frames(self, job_id: str) -> list[dict]:
        """The frames on disk of a job, by frame number."""
        return [
            {**dict(r), "resumed": bool(r["resumed"]), "outputs": json.loads(r["outputs"])}
            for r in self._conn().execute("SELECT * FROM frames WHERE job_id=? ORDER BY frame", (job_id,))
        ]

    def list_jobs(
        self,
        *,
        state: str | None = None,
        name: str | None = None,
        limit: int = 100,
        before_seq: int | None = None,
    ) -> list[dict]:
        """Jobs newest first; ``name`` matches a part of the name, case-insensitively."""
        q = "SELECT * FROM jobs"
        cond: list[str] = []
        args: list[Any] = []
        if state:
            cond.append("state=?")
            args.append(state)
        if name:
            cond.append("name LIKE ? ESCAPE '\\'")
            args.append("%" + name.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%")
        if before_seq is not None:
            cond.append("seq<?")
            args.append(before_seq)
        if cond:
            q += " WHERE " + " AND ".join(cond)
        q += " ORDER BY seq DESC LIMIT ?"
        args.append(limit)
        return [_job_dict(r) for r in self._conn().execute(q, args)]

    def counts(self) -> dict[str, int]:
        """Jobs per state (every state, zero included)."""
        out = {s: 0 for s in JOB_STATES}
        for r in self._conn().execute("SELECT state, COUNT(*) AS n FROM jobs GROUP BY state"):
            out[r["state"]] = r["n"]
        return out

    def request_cancel(self, job_id: str) -> dict | None:
        """Mark a job for cancellation; queued tasks are canceled at once.

        Returns the job, or None if unknown.  Running tasks are stopped by the dispatcher,
        which sees ``cancel_requested`` on its next tick.
        """
        with self._tx() as tx:
            job = self._job_row(tx.db, job_id)
            if job is None:
                return None
            if job["state"] in TERMINAL:
                return job
            tx.execute("UPDATE jobs SET cancel_requested=1 WHERE id=?", (job_id,))
            tx.execute(
                "UPDATE tasks SET state='canceled', finished=?, message='canceled' WHERE job_id=? AND state='queued'",
                (time.time(), job_id),
            )
            tx.event(job_id, "cancel", {"message": "cancel requested"})
            self._refresh_job(tx, job_id)
            return self._job_row(tx.db, job_id)

    def resume_job(self, job_id: str) -> dict | None:
        """Requeue the failed or canceled tasks of a finished job (fresh attempt budget).

        Frames already on disk are not rendered again: the dispatcher tells each task which.
        """
        with self._tx() as tx:
            job = self._job_row(tx.db, job_id)
            if job is None or job["state"] not in ("failed", "canceled"):
                return job
            tx.execute(
                "UPDATE tasks SET state='queued', attempt=0, error=NULL, progress=0, message='resumed',"
                " lease_owner=NULL, lease_expires=NULL, finished=NULL, eta_s=NULL"
                " WHERE job_id=? AND state IN ('failed','canceled')",
                (job_id,),
            )
            tx.execute("UPDATE jobs SET cancel_requested=0, error=NULL, finished=NULL WHERE id=?", (job_id,))
            tx.event(job_id, "retry", {"message": "resumed"})
            self._refresh_job(tx, job_id)
            return self._job_row(tx.db, job_id)

    def requeue_task(self, job_id: str, index: int, frames: Iterable[int] | None = None) -> dict | None:
        """Queue one finished task again (fresh attempt budget); None if there is no such task.

        ``frames``: the frames whose records are dropped (they render again); by default all
        of the task's.  Raises :class:`ValueError` while the task is queued or running.
        """
        with self._tx() as tx:
            t = tx.execute("SELECT * FROM tasks WHERE job_id=? AND idx=?", (job_id, index)).fetchone()
            if t is None:
                return None
            if t["state"] not in TERMINAL:
                raise ValueError(f"task {index} is {t['state']}")
            spec = TaskSpec.model_validate_json(t["spec"])
            drop = list(spec.frames or ()) if frames is None else list(frames)
            if drop:
                tx.executemany("DELETE FROM frames WHERE job_id=? AND frame=?", [(job_id, f) for f in drop])
            tx.execute(
                "UPDATE tasks SET state='queued', attempt=0, error=NULL, progress=0, message='requeued',"
                " lease_owner=NULL, lease_expires=NULL, finished=NULL, result=NULL, eta_s=NULL, seconds=NULL,"
                " frame=NULL, passes_done=NULL, passes_total=NULL WHERE id=?",
                (t["id"],),
            )
            tx.execute(
                "UPDATE jobs SET cancel_requested=0, error=NULL, finished=NULL, result=NULL,"
                " frames_done=(SELECT COUNT(*) FROM frames WHERE job_id=?) WHERE id=?",
                (job_id, job_id),
            )
            tx.event(job_id, "task", {"task": index, "state": "queued", "attempt": 0, "message": "requeued"})
            self._refresh_job(tx, job_id)
            return self._job_row(tx.db, job_id)

    def delete_job(self, job_id: str) -> bool:
        """Forget a finished job (rows, frames, events).  Raises :class:`ValueError` while it is active."""
        with self._tx() as tx:
            r = tx.execute("SELECT state FROM jobs WHERE id=?", (job_id,)).fetchone()
            if r is None:
                return False
            if r["state"] not in TERMINAL:
                raise ValueError(f"job {job_id} is {r['state']}")
            self._delete(tx, [job_id])
            return True

    @staticmethod
    def _delete(tx: Store._Tx, ids: list[str]) -> None:
        for table, col in (("events", "job_id"), ("frames", "job_id"), ("tasks", "job_id"), ("jobs", "id")):
            tx.executemany(f"DELETE FROM {table} WHERE {col}=?", [(i,) for i in ids])

    def mark_outputs_deleted(self, job_id: str) -> None:
        """Record that a job's outputs were deleted (preview and frames forgotten), with an ``outputs`` event."""
        with self._tx() as tx:
            tx.execute("UPDATE jobs SET outputs_deleted=1, preview=NULL WHERE id=?", (job_id,))
            tx.execute("DELETE FROM frames WHERE job_id=?", (job_id,))
            tx.event(job_id, "outputs", {"message": "outputs deleted"})

    # -- retention ---------------------------------------------------------------
    def prune(
        self,
        *,
        max_age_s: float | None,
        max_jobs: int | None,
        events_max_age_s: float | None,
        now: float | None = None,
    ) -> tuple[list[str], int]:
        """Forget finished jobs older than ``max_age_s`` or beyond the newest ``max_jobs``,
        and the events of jobs finished more than ``events_max_age_s`` ago.

        Returns ``(pruned job ids, events deleted)``.  Job folders are not touched here.
        """
        now = time.time() if now is None else now
        with self._tx() as tx:
            done = tx.execute(
                "SELECT id, finished FROM jobs WHERE state IN ('succeeded','failed','canceled')"
                " ORDER BY finished DESC, seq DESC"
            ).fetchall()
            ids = [
                r["id"]
                for i, r in enumerate(done)
                if (max_jobs is not None and i >= max_jobs)
                or (max_age_s is not None and (r["finished"] or 0.0) < now - max_age_s)
            ]
            if ids:
                self._delete(tx, ids)
            events = 0
            if events_max_age_s is not None:
                events = tx.execute(
                    "DELETE FROM events WHERE job_id IN (SELECT id FROM jobs WHERE"
                    " state IN ('succeeded','failed','canceled') AND finished < ?)",
                    (now - events_max_age_s,),
                ).rowcount
            return ids, events

    # -- dispatcher side -------------------------------------------------------
    def claim_next(self, owner: str, lease_s: float, *, worker: str | None = None) -> TaskRun | None:
        """Move the highest-priority, oldest queued task to running with a new attempt and lease."""
        now = time.time()
        with self._tx() as tx:
            r = tx.execute(
                "SELECT t.id, t.job_id, t.idx, t.spec, t.attempt, j.kind, j.config FROM tasks t"
                " JOIN jobs j ON j.id = t.job_id"
                " WHERE t.state='queued' AND j.cancel_requested=0"
                " ORDER BY t.priority DESC, t.id LIMIT 1"
            ).fetchone()
            if r is None:
                return None
            attempt = r["attempt"] + 1
            tx.execute(
                "UPDATE tasks SET state='running', attempt=?, lease_owner=?, lease_expires=?, worker=?,"
                " started=?, finished=NULL, progress=0, eta_s=NULL, frame=NULL, passes_done=NULL,"
                " passes_total=NULL, message=? WHERE id=?",
                (attempt, owner, now + lease_s, worker, now, f"starting (attempt {attempt})", r["id"]),
            )
            tx.event(r["job_id"], "task", {"task": r["idx"], "state": "running", "attempt": attempt})
            self._refresh_job(tx, r["job_id"])
            return TaskRun(
                task_id=r["id"],
                attempt=attempt,
                job_id=r["job_id"],
                kind=r["kind"],
                index=r["idx"],
                spec=TaskSpec.model_validate_json(r["spec"]).model_copy(update={"config": r["config"]}),
                lease_owner=owner,
            )

    def set_worker(self, task_id: int, attempt: int, worker: str) -> None:
        """Record where an attempt runs (only while that attempt is running)."""
        with self._tx() as tx:
            tx.execute(
                "UPDATE tasks SET worker=? WHERE id=? AND attempt=? AND state='running'", (worker, task_id, attempt)
            )

    def heartbeat(self, task_id: int, attempt: int, lease_s: float) -> bool:
        """Renew the lease of a running attempt; False when the attempt is stale."""
        with self._tx() as tx:
            n = tx.execute(
                "UPDATE tasks SET lease_expires=? WHERE id=? AND attempt=? AND state='running'",
                (time.time() + lease_s, task_id, attempt),
            ).rowcount
        return n == 1

    def _running(self, tx: Store._Tx, task_id: int, attempt: int) -> sqlite3.Row | None:
        return tx.execute(
            "SELECT job_id, idx, max_attempts, started FROM tasks WHERE id=? AND attempt=? AND state='running'",
            (task_id, attempt),
        ).fetchone()

    def report_progress(self, p: Progress, lease_s: float | None = None) -> bool:
        """Record progress of a running attempt (also renews its lease); False when stale."""
        fraction = min(1.0, max(0.0, float(p.fraction)))
        message = p.message[:500]
        with self._tx() as tx:
            row = self._running(tx, p.task_id, p.attempt)
            if row is None:
                return False
            sets = ["progress=?", "message=?"]
            args: list[Any] = [fraction, message]
            for col, value in (
                ("frame", p.frame),
                ("passes_done", p.passes_done),
                ("passes_total", p.passes_total),
                ("eta_s", p.eta_s),
                ("preview", p.preview),
            ):
                if value is not None:
                    sets.append(f"{col}=?")
                    args.append(value)
            if lease_s is not None:
                sets.append("lease_expires=?")
                args.append(time.time() + lease_s)
            tx.execute(f"UPDATE tasks SET {', '.join(sets)} WHERE id=?", args + [p.task_id])
            job_id = row["job_id"]
            prog = self._job_progress(tx, job_id)
            jsets, jargs = ["progress=?", "message=?"], [prog, message]
            if p.preview:
                jsets.append("preview=?")
                jargs.append(p.preview)
            if p.trees is not None:
                jsets.append("trees=?")
                jargs.append(int(p.trees))
            tx.execute(f"UPDATE jobs SET {', '.join(jsets)} WHERE id=?", jargs + [job_id])
            data: dict[str, Any] = {"task": row["idx"], "progress": prog, "task_progress": fraction, "message": message}
            for key, value in (
                ("frame", p.frame),
                ("passes_done", p.passes_done),
                ("passes_total", p.passes_total),
                ("eta_s", p.eta_s),
                ("preview", p.preview),
                ("trees", p.trees),
            ):
                if value is not None:
                    data[key] = value
            tx.event(job_id, "progress", data)
            return True

    def frame_done(self, f: FrameDone) -> bool:
        """Record a frame on disk; a resumed frame keeps the record of the attempt that rendered it."""
        with self._tx() as tx:
            row = self._running(tx, f.task_id, f.attempt)
            if row is None:
                return False
            job_id = row["job_id"]
            verb = "INSERT OR IGNORE" if f.resumed else "INSERT OR REPLACE"
            tx.execute(
                f"{verb} INTO frames(job_id, frame, task_idx, attempt, seconds, finished, resumed, thumb, outputs)"
                " VALUES (?,?,?,?,?,?,?,?,?)",
                (
                    job_id,
                    f.frame,
                    row["idx"],
                    f.attempt,
                    float(f.seconds),
                    time.time(),
                    int(f.resumed),
                    f.thumb,
                    json.dumps(f.outputs),
                ),
            )
            n = tx.execute("SELECT COUNT(*) FROM frames WHERE job_id=?", (job_id,)).fetchone()[0]
            tx.execute("UPDATE jobs SET frames_done=? WHERE id=?", (n, job_id))
            tx.event(
                job_id,
                "frame",
                {
                    "task": row["idx"],
                    "frame": f.frame,
                    "seconds": round(float(f.seconds), 3),
                    "thumb": f.thumb,
                    "resumed": f.resumed,
                    "frames_done": n,
                },
            )
            return True

    def finish_task(self, report: Done | Failed) -> bool:
        """Finish a running attempt as succeeded/failed; False (and no change) when stale."""
        now = time.time()
        with self._tx() as tx:
            row = self._running(tx, report.task_id, report.attempt)
            if row is None:
                return False
            job_id = row["job_id"]
            seconds = now - (row["started"] or now)
            if isinstance(report, Done):
                res = report.result
                if res.preview:
                    tx.execute("UPDATE jobs SET preview=? WHERE id=?", (res.preview, job_id))
                if res.trees is not None:
                    tx.execute("UPDATE jobs SET trees=? WHERE id=?", (res.trees, job_id))
                tx.execute(
                    "UPDATE tasks SET state='succeeded', result=?, error=NULL, finished=?, seconds=?,"
                    " lease_owner=NULL, lease_expires=NULL, progress=1.0, eta_s=0, message='succeeded',"
                    " preview=COALESCE(?, preview) WHERE id=?",
                    (res.model_dump_json(), now, seconds, res.preview, report.task_id),
                )
                tx.event(job_id, "task", {"task": row["idx"], "state": "succeeded", "attempt": report.attempt})
            else:
                err = report.error
                tx.execute(
                    "UPDATE tasks SET state='failed', error=?, finished=?, seconds=?, lease_owner=NULL,"
                    " lease_expires=NULL, eta_s=NULL, message=? WHERE id=?",
                    (err, now, seconds, err[:500], report.task_id),
                )
                tx.event(
                    job_id,
                    "task",
                    {"task": row["idx"], "state": "failed", "attempt": report.attempt, "error": err},
                )
                self._fail_siblings(tx, job_id, f"task {row['idx']}: {err}")
            self._refresh_job(tx, job_id)
            return True

    @staticmethod
    def _fail_siblings(tx: Store._Tx, job_id: str, error: str) -> None:
        """One failed task fails the job: its queued siblings are canceled (resume runs them)."""
        tx.execute(
            "UPDATE tasks SET state='canceled', finished=?, message='canceled: another task failed'"
            " WHERE job_id=? AND state='queued'",
            (time.time(), job_id),
        )
        tx.execute("UPDATE jobs SET error=COALESCE(error, ?) WHERE id=?", (error, job_id))

    def lose_attempt(self, task_id: int, attempt: int, reason: str) -> str | None:
        """The worker of a running attempt is gone: requeue (within the retry limit) or fail.

        Returns the new task state, or None if the attempt was stale.
        """
        with self._tx() as tx:
            row = self._running(tx, task_id, attempt)
            if row is None:
                return None
            job_id = row["job_id"]
            cancel = tx.execute("SELECT cancel_requested FROM jobs WHERE id=?", (job_id,)).fetchone()[0]
            now = time.time()
            if cancel:
                new = "canceled"
                tx.execute(
                    "UPDATE tasks SET state='canceled', finished=?, lease_owner=NULL, lease_expires=NULL,"
                    " eta_s=NULL, message='canceled' WHERE id=?",
                    (now, task_id),
                )
            elif attempt < row["max_attempts"]:
                new = "queued"
                tx.execute(
                    "UPDATE tasks SET state='queued', lease_owner=NULL, lease_expires=NULL, progress=0,"
                    " eta_s=NULL, frame=NULL, message=? WHERE id=?",
                    (f"requeued: {reason}", task_id),
                )
            else:
                new = "failed"
                err = f"{reason} on all {attempt} attempts"
                tx.execute(
                    "UPDATE tasks SET state='failed', finished=?, error=?, lease_owner=NULL,"
                    " lease_expires=NULL, eta_s=NULL, message=? WHERE id=?",
                    (now, err, err, task_id),
                )
                self._fail_siblings(tx, job_id, f"task {row['idx']}: {err}")
            tx.event(job_id, "task", {"task": row["idx"], "state": new, "attempt": attempt, "message": reason})
            self._refresh_job(tx, job_id)
            return new

    def cancel_running(self, task_id: int, attempt: int) -> bool:
        """A running attempt of a canceled job was stopped."""
        with self._tx() as tx:
            row = self._running(tx, task_id, attempt)
            if row is None:
                return False
            tx.execute(
                "UPDATE tasks SET state='canceled', finished=?, lease_owner=NULL, lease_expires=NULL,"
                " eta_s=NULL, message='canceled' WHERE id=?",
                (time.time(), task_id),
            )
            tx.event(row["job_id"], "task", {"task": row["idx"], "state": "canceled", "attempt": attempt})
            self._refresh_job(tx, row["job_id"])
            return True

    def running_tasks(self) -> list[dict]:
        """Every running task, with its job's ``cancel_requested``."""
        return [
            _task_dict(r)
            for r in self._conn().execute(
                "SELECT t.*, j.cancel_requested FROM tasks t JOIN jobs j ON j.id=t.job_id WHERE t.state='running'"
            )
        ]

    def expired_leases(self, now: float | None = None) -> list[tuple[int, int]]:
        """(task id, attempt) of each running attempt whose lease expired before ``now`` (default: the time now)."""
        now = time.time() if now is None else now
        return [
            (r["id"], r["attempt"])
            for r in self._conn().execute(
                "SELECT id, attempt FROM tasks WHERE state='running' AND lease_expires < ?", (now,)
            )
        ]

    def requeue_running(self, reason: str) -> int:
        """Requeue every running task (used at start-up: their workers died with the old process)."""
        with self._tx() as tx:
            rows = tx.execute(
                "SELECT t.id, t.job_id, t.idx, j.cancel_requested FROM tasks t"
                " JOIN jobs j ON j.id=t.job_id WHERE t.state='running'"
            ).fetchall()
            for r in rows:
                new = "canceled" if r["cancel_requested"] else "queued"
                tx.execute(
                    "UPDATE tasks SET state=?, lease_owner=NULL, lease_expires=NULL, progress=0, eta_s=NULL,"
                    " frame=NULL, message=? WHERE id=?",
                    (new, f"requeued: {reason}" if new == "queued" else "canceled", r["id"]),
                )
                tx.event(r["job_id"], "task", {"task": r["idx"], "state": new, "message": reason})
            for job_id in {r["job_id"] for r in rows}:
                self._refresh_job(tx, job_id)
            return len(rows)

    # -- derived job state -----------------------------------------------------
    @staticmethod
    def _job_progress(tx: Store._Tx, job_id: str) -> float:
        r = tx.execute(
            "SELECT AVG(CASE WHEN state='succeeded' THEN 1.0 ELSE progress END) FROM tasks WHERE job_id=?", (job_id,)
        ).fetchone()
        return float(r[0] or 0.0)

    def _refresh_job(self, tx: Store._Tx, job_id: str) -> None:
        job = tx.execute("SELECT state, cancel_requested, started FROM jobs WHERE id=?", (job_id,)).fetchone()
        counts = {
            r["state"]: r["n"]
            for r in tx.execute("SELECT state, COUNT(*) AS n FROM tasks WHERE job_id=? GROUP BY state", (job_id,))
        }
        running, queued = counts.get("running", 0), counts.get("queued", 0)
        if not running and not queued:  # nothing left to run: the job is over
            if counts.get("failed", 0):
                new = "failed"
            elif counts.get("canceled", 0) or job["cancel_requested"]:
                new = "canceled"
            else:
                new = "succeeded"
        elif running or sum(counts.get(s, 0) for s in TERMINAL):
            new = "running"
        else:
            new = "queued"
        now = time.time()
        prog = self._job_progress(tx, job_id)
        if new == job["state"]:
            tx.execute("UPDATE jobs SET progress=? WHERE id=?", (prog, job_id))
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
                    TaskResult.model_validate_json(r["result"]) if r["result"] else TaskResult()
                    for r in tx.execute("SELECT result FROM tasks WHERE job_id=? ORDER BY idx", (job_id,))
                ]
                sets.append("result=?")
                args.append(json.dumps(merge_results(results)))
        else:
            sets.append("finished=NULL")
        tx.execute(f"UPDATE jobs SET {', '.join(sets)} WHERE id=?", args + [job_id])
        tx.event(job_id, "state", {"state": new, "progress": prog})


def merge_results(results: Iterable[TaskResult]) -> dict:
    """The job's outputs (every task's, sorted, once each) and per-task statistics in task order."""
    outputs: set[str] = set()
    stats: list[dict] = []
    for r in results:
        outputs.update(r.outputs)
        if r.stats is not None:
            stats.append(r.stats)
    return {"outputs": sorted(outputs), "stats": stats}


def _job_dict(r: sqlite3.Row) -> dict:
    d = dict(r)
    d["settings"] = json.loads(d["settings"])
    d["result"] = json.loads(d["result"]) if d["result"] else None
    d["cancel_requested"] = bool(d["cancel_requested"])
    d["outputs_deleted"] = bool(d.get("outputs_deleted"))
    return d


def _task_dict(r: sqlite3.Row) -> dict:
    """A task row; ``spec`` stays JSON text (see :func:`task_spec`), ``frames`` is its frame list."""
    d = dict(r)
    listed = d.pop("frame_list", None)
    d["frames"] = json.loads(listed) if listed else json.loads(d["spec"]).get("frames")
    d["result"] = json.loads(d["result"]) if d["result"] else None
    return d


def task_spec(task: dict) -> TaskSpec:
    """The :class:`TaskSpec` of a task row (without the job's config text)."""
    return TaskSpec.model_validate_json(task["spec"])
