"""The job store's state machine, its migration, retention, and the notifications SSE waits on."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
import time

import pytest

from forest.service.assets import DataDir
from forest.service.models import Done, Failed, FrameDone, Progress, TaskResult, TaskSpec, parse_report
from forest.service.notify import Notifier
from forest.service.retention import Retention, read_manifest, sweep, write_manifest
from forest.service.store import Store


def specs(n: int, *, frames: bool = False) -> list[TaskSpec]:
    return [
        TaskSpec(
            job_id="0" * 32,
            kind="flythrough" if frames else "render",
            index=i,
            config="x = 1",
            output="out/frame_####.exr" if frames else "out/render.exr",
            frames=(i + 1,) if frames else None,
        )
        for i in range(n)
    ]


def new_job(s: Store, n: int = 1, **kw) -> str:
    job, created = s.create_job(
        kind=kw.pop("kind", "render"),
        config="x = 1",
        settings={},
        priority=kw.pop("priority", 0),
        task_specs=specs(n, **kw),
    )
    assert created
    return job["id"]


def finish(s: Store, state: str = "succeeded") -> str:
    run = s.claim_next("o", 10)
    if state == "succeeded":
        s.finish_task(Done(task_id=run.task_id, attempt=run.attempt, result=TaskResult(outputs=["out/a.png"])))
    else:
        s.finish_task(Failed(task_id=run.task_id, attempt=run.attempt, error="boom"))
    return run.job_id


def test_stale_attempt_reports_are_ignored(tmp_path):
    s = Store(tmp_path / "db.sqlite3", max_attempts=2)
    jid = new_job(s)
    first = s.claim_next("a", 10)
    assert first.attempt == 1 and s.get_job(jid)["state"] == "running"
    assert s.lose_attempt(first.task_id, 1, "lost") == "queued"
    second = s.claim_next("b", 10)
    assert second.task_id == first.task_id and second.attempt == 2
    # the first attempt's worker is still talking: none of it counts
    stale = {"task_id": first.task_id, "attempt": 1}
    assert not s.heartbeat(first.task_id, 1, 10)
    assert not s.report_progress(Progress(**stale, fraction=0.9, message="stale"))
    assert not s.frame_done(FrameDone(**stale, frame=1))
    assert not s.finish_task(Done(**stale, result=TaskResult(outputs=["stale"])))
    assert s.lose_attempt(first.task_id, 1, "lost again") is None
    t = s.get_job(jid, with_tasks=True)["tasks"][0]
    assert t["state"] == "running" and t["attempt"] == 2 and t["progress"] == 0.0
    assert s.report_progress(Progress(task_id=second.task_id, attempt=2, fraction=0.5, message="half", eta_s=3.0))
    assert s.get_job(jid, with_tasks=True)["tasks"][0]["eta_s"] == 3.0
    # the retry limit: losing the last attempt fails the job
    assert s.lose_attempt(second.task_id, 2, "lost") == "failed"
    j = s.get_job(jid)
    assert j["state"] == "failed" and "2 attempts" in j["error"]
    s.close()


def test_priority_then_age_orders_the_queue(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    made = [new_job(s, priority=p) for p in (0, 5, 0, 5, -1)]
    order = [s.claim_next("o", 10).job_id for _ in range(5)]
    assert order == [made[1], made[3], made[0], made[2], made[4]]
    assert s.claim_next("o", 10) is None
    s.close()


def test_restart_requeues_running_tasks_in_the_store(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    jid = new_job(s, 3, kind="flythrough", frames=True)
    a = s.claim_next("o", 10)
    s.finish_task(Done(task_id=a.task_id, attempt=a.attempt, result=TaskResult(outputs=["out/a.png"])))
    b = s.claim_next("o", 10)
    s.close()
    s2 = Store(tmp_path / "db.sqlite3")
    assert s2.requeued_on_open == 1
    tasks = s2.get_job(jid, with_tasks=True)["tasks"]
    assert [t["state"] for t in tasks] == ["succeeded", "queued", "queued"]
    assert s2.claim_next("o", 10).attempt == b.attempt + 1
    s2.close()


def test_frames_are_recorded_once_and_a_resumed_frame_keeps_its_first_record(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    jid = new_job(s, 2, kind="flythrough", frames=True)
    run = s.claim_next("o", 10)
    assert s.frame_done(FrameDone(task_id=run.task_id, attempt=run.attempt, frame=1, seconds=2.5, outputs=["a"]))
    s.lose_attempt(run.task_id, run.attempt, "lost")
    run2 = s.claim_next("o", 10)
    assert s.frame_done(FrameDone(task_id=run2.task_id, attempt=run2.attempt, frame=1, resumed=True))
    (rec,) = s.frames(jid)
    assert rec["attempt"] == 1 and rec["seconds"] == 2.5 and not rec["resumed"]
    assert s.get_job(jid)["frames_done"] == 1 and s.get_job(jid)["frames_total"] == 2
    s.close()


def test_requeue_of_one_task_reopens_a_finished_job(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    jid = new_job(s, 2, kind="flythrough", frames=True)
    for _ in range(2):
        run = s.claim_next("o", 10)
        s.frame_done(FrameDone(task_id=run.task_id, attempt=run.attempt, frame=run.index + 1))
        s.finish_task(Done(task_id=run.task_id, attempt=run.attempt, result=TaskResult()))
    assert s.get_job(jid)["state"] == "succeeded" and s.get_job(jid)["frames_done"] == 2
    s.requeue_task(jid, 1)
    job = s.get_job(jid, with_tasks=True)
    assert job["state"] == "running" and job["finished"] is None and job["frames_done"] == 1
    assert [t["state"] for t in job["tasks"]] == ["succeeded", "queued"] and job["tasks"][1]["attempt"] == 0
    run = s.claim_next("o", 10)
    with pytest.raises(ValueError):
        s.requeue_task(jid, 1)  # it runs
    s.finish_task(Done(task_id=run.task_id, attempt=run.attempt, result=TaskResult()))
    assert s.get_job(jid)["state"] == "succeeded"
    s.close()


def test_a_failed_task_cancels_its_queued_siblings_and_resume_runs_them(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    jid = new_job(s, 3, kind="flythrough", frames=True)
    finish(s, "failed")
    job = s.get_job(jid, with_tasks=True)
    assert job["state"] == "failed" and [t["state"] for t in job["tasks"]] == ["failed", "canceled", "canceled"]
    s.resume_job(jid)
    assert [t["state"] for t in s.get_job(jid, with_tasks=True)["tasks"]] == ["queued"] * 3
    for _ in range(3):
        finish(s)
    assert s.get_job(jid)["state"] == "succeeded"
    s.close()


def test_reports_round_trip_through_json_lines():
    p = Progress(task_id=3, attempt=2, fraction=0.5, message="frame 4: pass 2/8", frame=4, passes_done=2)
    assert parse_report(p.model_dump_json()) == p
    f = FrameDone(task_id=3, attempt=2, frame=4, files={"out/x.png": b"\x89PNG\x00\xff"})
    assert parse_report(f.model_dump_json()).files == {"out/x.png": b"\x89PNG\x00\xff"}
    with pytest.raises(ValueError):
        parse_report('{"type": "progress", "task_id": 1}')


def test_a_first_version_store_is_migrated_in_place(tmp_path):
    path = tmp_path / "jobs.sqlite3"
    db = sqlite3.connect(path)
    db.executescript(
        """
        CREATE TABLE jobs (id TEXT PRIMARY KEY, seq INTEGER NOT NULL, kind TEXT NOT NULL, state TEXT NOT NULL,
            priority INTEGER NOT NULL DEFAULT 0, config TEXT NOT NULL, settings TEXT NOT NULL,
            idempotency_key TEXT UNIQUE, request_hash TEXT, created REAL NOT NULL, started REAL, finished REAL,
            progress REAL NOT NULL DEFAULT 0, message TEXT NOT NULL DEFAULT '', error TEXT,
            cancel_requested INTEGER NOT NULL DEFAULT 0, preview TEXT, result TEXT);
        CREATE TABLE tasks (id INTEGER PRIMARY KEY AUTOINCREMENT, job_id TEXT NOT NULL, idx INTEGER NOT NULL,
            state TEXT NOT NULL, priority INTEGER NOT NULL DEFAULT 0, spec TEXT NOT NULL,
            attempt INTEGER NOT NULL DEFAULT 0, max_attempts INTEGER NOT NULL DEFAULT 3, lease_owner TEXT,
            lease_expires REAL, worker TEXT, progress REAL NOT NULL DEFAULT 0, message TEXT NOT NULL DEFAULT '',
            preview TEXT, result TEXT, error TEXT, started REAL, finished REAL);
        CREATE TABLE events (id INTEGER PRIMARY KEY AUTOINCREMENT, job_id TEXT NOT NULL, type TEXT NOT NULL,
            data TEXT NOT NULL, ts REAL NOT NULL);
        INSERT INTO jobs(id, seq, kind, state, config, settings, created)
            VALUES ('a' || hex(zeroblob(15)), 1, 'render', 'succeeded', 'x = 1', '{"name": "old take"}', 1.0);
        """
    )
    db.commit()
    db.close()
    s = Store(path)
    (job,) = s.list_jobs()
    assert job["name"] == "old take" and job["frames_done"] == 0 and job["trees"] is None
    assert [j["name"] for j in s.list_jobs(name="TAKE")] == ["old take"]
    new_job(s)
    assert s.counts()["queued"] == 1
    s.close()


# -- retention ---------------------------------------------------------------------------


def test_retention_prunes_by_count_and_age_and_keeps_folders(tmp_path):
    data = DataDir(tmp_path / "data")
    s = Store(data.db)
    ids = []
    for _ in range(4):
        jid = new_job(s)
        finish(s)
        (data.job_dir(jid) / "out").mkdir(parents=True)
        (data.job_dir(jid) / "out" / "a.png").write_bytes(b"x" * 10)
        write_manifest(data, s, jid)
        ids.append(jid)
        time.sleep(0.01)
    running = new_job(s)
    s.claim_next("o", 10)
    # the newest two finished jobs stay; the running one is never pruned
    done = sweep(s, data, Retention(max_age_s=None, max_jobs=2, events_max_age_s=None))
    assert sorted(done["pruned"]) == sorted(ids[:2])
    assert [s.get_job(j) is not None for j in ids] == [False, False, True, True] and s.get_job(running)
    assert read_manifest(data, ids[0])["archived"] and (data.job_dir(ids[0]) / "out" / "a.png").is_file()
    # by age: everything finished before "now + 1 h - 10 min" goes; events of finished jobs too
    later = time.time() + 3600
    done = sweep(s, data, Retention(max_age_s=600, max_jobs=None, events_max_age_s=600), now=later)
    assert sorted(done["pruned"]) == sorted(ids[2:]) and s.counts()["succeeded"] == 0
    assert s.events_after(running, 0)  # a running job keeps its events
    s.close()


def test_output_quota_deletes_the_oldest_finished_outputs_first(tmp_path):
    data = DataDir(tmp_path / "data")
    s = Store(data.db)
    ids = []
    for _ in range(3):
        jid = new_job(s)
        finish(s)
        (data.job_dir(jid) / "out").mkdir(parents=True)
        (data.job_dir(jid) / "out" / "frame.exr").write_bytes(b"x" * 1000)
        (data.job_dir(jid) / "job.log").write_text("kept\n")
        ids.append(jid)
        time.sleep(0.01)
    done = sweep(s, data, Retention(max_age_s=None, max_jobs=None, events_max_age_s=None, output_quota_bytes=2100))
    assert done["outputs_deleted"] == ids[:1]
    assert not (data.job_dir(ids[0]) / "out").exists() and (data.job_dir(ids[0]) / "job.log").is_file()
    assert (data.job_dir(ids[1]) / "out" / "frame.exr").is_file()
    assert s.get_job(ids[0])["outputs_deleted"] and not s.get_job(ids[1])["outputs_deleted"]
    s.close()


# -- notifications ------------------------------------------------------------------------


def test_store_writes_wake_subscribers_of_that_job_only(tmp_path):
    notifier = Notifier()
    s = Store(tmp_path / "db.sqlite3", on_events=notifier.publish)
    jid = new_job(s)
    other = new_job(s)

    async def main() -> tuple[bool, bool]:
        with notifier.subscribe(jid) as mine, notifier.subscribe(other) as theirs:
            assert notifier.subscribers() == 2
            threading.Thread(target=s.request_cancel, args=(jid,)).start()  # a write from another thread
            await asyncio.wait_for(mine.wait(), 5)
            return mine.is_set(), theirs.is_set()

    assert asyncio.run(main()) == (True, False)
    assert notifier.subscribers() == 0
    s.close()
