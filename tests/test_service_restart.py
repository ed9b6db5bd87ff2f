"""The job service survives being killed: queued and running work is kept and finished."""

from __future__ import annotations

import time

import httpx
import pytest

from forest.service.store import Store

from test_service_support import ServeProcess, pid_alive, tiny_config, wait_for, wait_job


def test_service_killed_and_restarted_loses_no_job(tmp_path):
    data = tmp_path / "data"
    srv = ServeProcess(data, "--workers", "1").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            ids = []
            for i in range(4):
                r = c.post(
                    "/jobs",
                    json={
                        "kind": "flythrough" if i == 0 else "render",
                        "config": tiny_config(),
                        "priority": 10 if i == 0 else 0,
                        "settings": {"frames": "1-6", "frames_per_task": 6} if i == 0 else {},
                    },
                )
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
            # the first (highest priority) job is rendering; the others wait in the queue
            task = wait_for(
                lambda: next(
                    (t for t in c.get(f"/jobs/{ids[0]}").json()["tasks"] if t["state"] == "running" and t["worker"]),
                    None,
                )
            )
            pid = int(task["worker"].split(":")[1])
            assert all(c.get(f"/jobs/{j}").json()["state"] == "queued" for j in ids[1:])
        srv.kill()
        # the orphaned worker notices its service is gone and exits by itself
        wait_for(lambda: not pid_alive(pid), timeout=15)
    finally:
        srv.stop()

    # the store on disk still has every job; the interrupted task is running in it
    import sqlite3

    db = sqlite3.connect(data / "jobs.sqlite3")
    rows = dict(db.execute("SELECT id, state FROM jobs").fetchall())
    db.close()
    assert set(rows) == set(ids) and rows[ids[0]] == "running"

    srv = ServeProcess(data, "--workers", "2").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            assert c.get("/health").json()["requeued_at_start"] == 1
            jobs = [wait_job(c, j) for j in ids]
            assert [j["state"] for j in jobs] == ["succeeded"] * 4, jobs
            assert jobs[0]["tasks"][0]["attempt"] == 2
            assert all(j["tasks"][0]["attempt"] == 1 for j in jobs[1:])
            listed = c.get("/jobs").json()
            assert listed["counts"]["succeeded"] == 4 and sum(listed["counts"].values()) == 4
            res = c.get(f"/jobs/{ids[0]}/result").json()
            assert len([o for o in res["outputs"] if o["path"].endswith(".png")]) == 6
    finally:
        srv.stop()


def test_lost_heartbeats_expire_the_lease_and_requeue(tmp_path):
    """A worker that stops (SIGSTOP: alive but silent) loses its lease; the task runs again elsewhere."""
    import os
    import signal

    srv = ServeProcess(tmp_path / "data", "--workers", "1", "--lease", "2").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            jid = c.post(
                "/jobs",
                json={
                    "kind": "flythrough",
                    "config": tiny_config(),
                    "settings": {"frames": "1-3", "frames_per_task": 3},
                },
            ).json()["id"]
            task = wait_for(
                lambda: next(
                    (t for t in c.get(f"/jobs/{jid}").json()["tasks"] if t["state"] == "running" and t["worker"]), None
                )
            )
            pid = int(task["worker"].split(":")[1])
            os.kill(pid, signal.SIGSTOP)
            t0 = time.monotonic()
            job = wait_job(c, jid)
            assert job["state"] == "succeeded" and job["tasks"][0]["attempt"] >= 2
            assert time.monotonic() - t0 >= 1.0
            assert "lease expired" in c.get(f"/jobs/{jid}/log").text
            wait_for(lambda: not pid_alive(pid), timeout=10)
    finally:
        srv.stop()


@pytest.mark.parametrize("attempts", [2])
def test_stale_attempt_reports_are_ignored(tmp_path, attempts):
    s = Store(tmp_path / "db.sqlite3", max_attempts=attempts)
    job, _ = s.create_job(kind="render", config="x", settings={}, priority=0, task_specs=[{"i": 0}])
    first = s.claim_next("a", 10)
    assert first.attempt == 1 and s.get_job(job["id"])["state"] == "running"
    assert s.lose_attempt(first.task_id, 1, "lost") == "queued"
    second = s.claim_next("b", 10)
    assert second.task_id == first.task_id and second.attempt == 2
    # the first attempt's worker is still talking: none of it counts
    assert not s.heartbeat(first.task_id, 1, 10)
    assert not s.report_progress(first.task_id, 1, 0.9, "stale")
    assert not s.finish_task(first.task_id, 1, "succeeded", result={"outputs": ["stale"]})
    assert s.lose_attempt(first.task_id, 1, "lost again") is None
    t = s.get_job(job["id"], with_tasks=True)["tasks"][0]
    assert t["state"] == "running" and t["attempt"] == 2 and t["progress"] == 0.0
    assert s.report_progress(second.task_id, 2, 0.5, "half")
    # the retry limit: losing the last attempt fails the job
    assert s.lose_attempt(second.task_id, 2, "lost") == "failed"
    j = s.get_job(job["id"])
    assert j["state"] == "failed" and "2 attempts" in j["error"]
    s.close()


def test_priority_then_age_orders_the_queue(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    made = [
        s.create_job(kind="render", config="x", settings={}, priority=p, task_specs=[{}])[0]["id"]
        for p in (0, 5, 0, 5, -1)
    ]
    order = [s.claim_next("o", 10).job_id for _ in range(5)]
    assert order == [made[1], made[3], made[0], made[2], made[4]]
    assert s.claim_next("o", 10) is None
    s.close()


def test_restart_requeues_running_tasks_in_the_store(tmp_path):
    s = Store(tmp_path / "db.sqlite3")
    job, _ = s.create_job(kind="flythrough", config="x", settings={}, priority=0, task_specs=[{}, {}, {}])
    a = s.claim_next("o", 10)
    s.finish_task(a.task_id, a.attempt, "succeeded", result={"outputs": ["out/a.png"]})
    b = s.claim_next("o", 10)
    s.close()
    s2 = Store(tmp_path / "db.sqlite3")
    assert s2.requeued_on_open == 1
    tasks = s2.get_job(job["id"], with_tasks=True)["tasks"]
    assert [t["state"] for t in tasks] == ["succeeded", "queued", "queued"]
    assert s2.claim_next("o", 10).attempt == b.attempt + 1
    s2.close()
