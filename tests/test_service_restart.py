"""The job service survives being killed: queued and running work is kept and finished, frames on disk stay."""

from __future__ import annotations

import os
import signal
import sqlite3
import time

import httpx

from test_service_support import ServeProcess, file_stamps, pid_alive, tiny_config, wait_for, wait_job


def running_pid(c: httpx.Client, jid: str) -> int:
    task = wait_for(
        lambda: next(
            (t for t in c.get(f"/jobs/{jid}").json()["tasks"] if t["state"] == "running" and t["worker"]), None
        )
    )
    return int(task["worker"].split(":")[1])


def test_service_killed_with_ten_jobs_queued_finishes_all_after_restart(tmp_path):
    data = tmp_path / "data"
    srv = ServeProcess(data, "--workers", "1").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            ids = []
            for i in range(11):
                r = c.post(
                    "/jobs",
                    json={
                        "kind": "flythrough" if i == 0 else "render",
                        "config": tiny_config(),
                        "priority": 10 if i == 0 else 0,
                        "settings": {"frames": "1-6", "frames_per_task": 6, "spp": 32} if i == 0 else {},
                    },
                )
                assert r.status_code == 202, r.text
                ids.append(r.json()["id"])
            # the first (highest priority) job is rendering; the ten others wait in the queue
            pid = running_pid(c, ids[0])
            assert all(c.get(f"/jobs/{j}").json()["state"] == "queued" for j in ids[1:])
        srv.kill()
        # the orphaned worker notices its service is gone and exits by itself
        wait_for(lambda: not pid_alive(pid), timeout=15)
    finally:
        srv.stop()

    # the store on disk still has every job; the interrupted task is running in it
    db = sqlite3.connect(data / "jobs.sqlite3")
    rows = dict(db.execute("SELECT id, state FROM jobs").fetchall())
    db.close()
    assert set(rows) == set(ids) and rows[ids[0]] == "running"

    srv = ServeProcess(data, "--workers", "2").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            assert c.get("/health").json()["requeued_at_start"] == 1
            jobs = [wait_job(c, j) for j in ids]
            assert [j["state"] for j in jobs] == ["succeeded"] * 11, jobs
            assert jobs[0]["tasks"][0]["attempt"] == 2
            assert all(j["tasks"][0]["attempt"] == 1 for j in jobs[1:])
            listed = c.get("/jobs").json()
            assert listed["counts"]["succeeded"] == 11 and listed["counts"]["total"] == 11
            res = c.get(f"/jobs/{ids[0]}/result").json()
            assert len([o for o in res["outputs"] if o["path"].endswith(".png") and "/frame_" in o["path"]]) == 12
    finally:
        srv.stop()


def test_resume_after_a_restart_renders_only_the_missing_frames(tmp_path):
    data = tmp_path / "data"
    srv = ServeProcess(data, "--workers", "1").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            r = c.post(
                "/jobs",
                json={
                    "kind": "flythrough",
                    "config": tiny_config(),
                    "settings": {"frames": "1-6", "frames_per_task": 6, "width": 96, "height": 72, "spp": 128},
                },
            )
            jid = r.json()["id"]
            out = data / "jobs" / jid / "out"
            wait_for(lambda: (out / "frame_0002.png").exists(), timeout=120)
        srv.kill()
        stamps = file_stamps(out, "frame_*")
    finally:
        srv.stop()
    # the frames that were whole (EXR and PNG) when the service died; a frame cut between its
    # two files is rendered again, as it should be
    whole = {k[:10] for k in stamps if k.endswith(".exr") and k[:10] + ".png" in stamps}
    before = {k: v for k, v in stamps.items() if k[:10] in whole}
    assert "frame_0002.exr" in before and "frame_0006.exr" not in before

    srv = ServeProcess(data, "--workers", "1").start()
    try:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            job = wait_job(c, jid, timeout=180)
            assert job["state"] == "succeeded" and job["frames_done"] == 6
            after = file_stamps(out, "frame_*")
            assert len(after) == 12 and {k: after[k] for k in before} == before
            frames = {f["frame"]: f for f in c.get(f"/jobs/{jid}/frames").json()}
            # a frame whole on disk but not yet recorded when the service died is reported
            # ``resumed`` by the second attempt, not rendered again
            rendered_again = [f for f in range(1, 7) if frames[f]["attempt"] == 2 and not frames[f]["resumed"]]
            assert rendered_again and min(rendered_again) > max(int(k[6:10]) for k in before)
            log = c.get(f"/jobs/{jid}/log").text
            assert "frames already on disk" in log and "not rendered again" in log
    finally:
        srv.stop()


def test_lost_heartbeats_expire_the_lease_and_requeue(tmp_path):
    """A worker that stops (SIGSTOP: alive but silent) loses its lease; the task runs again elsewhere."""
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
            pid = running_pid(c, jid)
            os.kill(pid, signal.SIGSTOP)
            t0 = time.monotonic()
            job = wait_job(c, jid)
            assert job["state"] == "succeeded" and job["tasks"][0]["attempt"] >= 2
            assert time.monotonic() - t0 >= 1.0
            assert "lease expired" in c.get(f"/jobs/{jid}/log").text
            wait_for(lambda: not pid_alive(pid), timeout=10)
    finally:
        srv.stop()
